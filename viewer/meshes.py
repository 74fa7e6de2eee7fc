"""One triangle mesh and one colour per URDF link, built from the URDF's boxes and cylinders.

The scene draws each link of every arm as one instanced ("batched") mesh: the geometry is sent
to the browser once, and each tick only moves the instances.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt
import trimesh
import yourdfpy

DEFAULT_RGB = (180, 180, 180)


@dataclass(frozen=True)
class LinkMesh:
    """A link's visuals merged into one mesh, in the link's frame, with its colour (0..255)."""

    link: str
    vertices: npt.NDArray[np.float32]
    faces: npt.NDArray[np.uint32]
    rgb: tuple[int, int, int]


def _primitive(geometry: yourdfpy.Geometry) -> trimesh.Trimesh:
    if geometry.box is not None:
        return trimesh.creation.box(extents=geometry.box.size)
    if geometry.cylinder is not None:
        return trimesh.creation.cylinder(
            radius=geometry.cylinder.radius, height=geometry.cylinder.length, sections=24
        )
    if geometry.sphere is not None:
        return trimesh.creation.icosphere(subdivisions=2, radius=geometry.sphere.radius)
    raise ValueError("the viewer's URDF may only use boxes, cylinders and spheres (no mesh files)")


def _rgb(urdf: yourdfpy.URDF, material: yourdfpy.Material | None) -> tuple[int, int, int]:
    if material is None:
        return DEFAULT_RGB
    color = material.color
    if color is None:
        named = {m.name: m for m in urdf.robot.materials}.get(material.name)
        color = None if named is None else named.color
    if color is None:
        return DEFAULT_RGB
    r, g, b = (int(round(255 * float(c))) for c in color.rgba[:3])
    return (r, g, b)


def link_meshes(urdf: yourdfpy.URDF, links: tuple[str, ...]) -> list[LinkMesh]:
    """Meshes of ``links`` (links without visuals are skipped); colour of the first visual."""
    out = []
    for name in links:
        visuals = urdf.link_map[name].visuals
        if not visuals:
            continue
        parts = []
        for visual in visuals:
            mesh = _primitive(visual.geometry)
            if visual.origin is not None:
                mesh.apply_transform(np.asarray(visual.origin))
            parts.append(mesh)
        merged = trimesh.util.concatenate(parts)
        out.append(
            LinkMesh(
                link=name,
                vertices=np.asarray(merged.vertices, dtype=np.float32),
                faces=np.asarray(merged.faces, dtype=np.uint32),
                rgb=_rgb(urdf, visuals[0].material),
            )
        )
    return out
