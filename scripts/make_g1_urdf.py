"""Write fleet/scene3d/assets/g1_29dof.urdf: the Unitree G1 (29 dof) drawn with primitives.

The kinematics (every joint's origin, axis and limits, the link names) are Unitree's published
``g1_29dof`` description (unitree_ros ``robots/g1_description``, the model mujoco-menagerie's
``unitree_g1`` also carries; both BSD-3-Clause, Unitree Robotics: see
fleet/scene3d/assets/g1_29dof.LICENSE). Its STL meshes are not shipped: each link is drawn as
"bones" (a cylinder from the link's origin to each child joint) plus a few boxes and spheres
(pelvis, torso, head, feet, hands), so the viewer loads no mesh file and sends few triangles.

Run once after changing the table: ``.venv/bin/python scripts/make_g1_urdf.py``; a test checks
the shipped file is this script's output.
"""

from __future__ import annotations

import math
import sys
from pathlib import Path

OUT = Path(__file__).resolve().parent.parent / "fleet" / "scene3d" / "assets" / "g1_29dof.urdf"

# ruff: noqa: E501  (the joint table reads best one joint a line, as in Unitree's URDF)
# fmt: off
# name, parent link, child link, origin xyz, origin rpy, axis, lower, upper (Unitree's g1_29dof)
JOINTS: tuple[tuple[str, str, str, tuple[float, ...], tuple[float, ...], str, float, float], ...] = (
    ("left_hip_pitch_joint", "pelvis", "left_hip_pitch_link", (0, 0.064452, -0.1027), (0, 0, 0), "0 1 0", -2.5307, 2.8798),
    ("left_hip_roll_joint", "left_hip_pitch_link", "left_hip_roll_link", (0, 0.052, -0.030465), (0, -0.1749, 0), "1 0 0", -0.5236, 2.9671),
    ("left_hip_yaw_joint", "left_hip_roll_link", "left_hip_yaw_link", (0.025001, 0, -0.12412), (0, 0, 0), "0 0 1", -2.7576, 2.7576),
    ("left_knee_joint", "left_hip_yaw_link", "left_knee_link", (-0.078273, 0.0021489, -0.17734), (0, 0.1749, 0), "0 1 0", -0.087267, 2.8798),
    ("left_ankle_pitch_joint", "left_knee_link", "left_ankle_pitch_link", (0, -9.4445e-05, -0.30001), (0, 0, 0), "0 1 0", -0.87267, 0.5236),
    ("left_ankle_roll_joint", "left_ankle_pitch_link", "left_ankle_roll_link", (0, 0, -0.017558), (0, 0, 0), "1 0 0", -0.2618, 0.2618),
    ("right_hip_pitch_joint", "pelvis", "right_hip_pitch_link", (0, -0.064452, -0.1027), (0, 0, 0), "0 1 0", -2.5307, 2.8798),
    ("right_hip_roll_joint", "right_hip_pitch_link", "right_hip_roll_link", (0, -0.052, -0.030465), (0, -0.1749, 0), "1 0 0", -2.9671, 0.5236),
    ("right_hip_yaw_joint", "right_hip_roll_link", "right_hip_yaw_link", (0.025001, 0, -0.12412), (0, 0, 0), "0 0 1", -2.7576, 2.7576),
    ("right_knee_joint", "right_hip_yaw_link", "right_knee_link", (-0.078273, -0.0021489, -0.17734), (0, 0.1749, 0), "0 1 0", -0.087267, 2.8798),
    ("right_ankle_pitch_joint", "right_knee_link", "right_ankle_pitch_link", (0, 9.4445e-05, -0.30001), (0, 0, 0), "0 1 0", -0.87267, 0.5236),
    ("right_ankle_roll_joint", "right_ankle_pitch_link", "right_ankle_roll_link", (0, 0, -0.017558), (0, 0, 0), "1 0 0", -0.2618, 0.2618),
    ("waist_yaw_joint", "pelvis", "waist_yaw_link", (0, 0, 0), (0, 0, 0), "0 0 1", -2.618, 2.618),
    ("waist_roll_joint", "waist_yaw_link", "waist_roll_link", (-0.0039635, 0, 0.035), (0, 0, 0), "1 0 0", -0.52, 0.52),
    ("waist_pitch_joint", "waist_roll_link", "torso_link", (0, 0, 0.019), (0, 0, 0), "0 1 0", -0.52, 0.52),
    ("left_shoulder_pitch_joint", "torso_link", "left_shoulder_pitch_link", (0.0039563, 0.10022, 0.23778), (0.27931, 5.4949e-05, -0.00019159), "0 1 0", -3.0892, 2.6704),
    ("left_shoulder_roll_joint", "left_shoulder_pitch_link", "left_shoulder_roll_link", (0, 0.038, -0.013831), (-0.27925, 0, 0), "1 0 0", -1.5882, 2.2515),
    ("left_shoulder_yaw_joint", "left_shoulder_roll_link", "left_shoulder_yaw_link", (0, 0.00624, -0.1032), (0, 0, 0), "0 0 1", -2.618, 2.618),
    ("left_elbow_joint", "left_shoulder_yaw_link", "left_elbow_link", (0.015783, 0, -0.080518), (0, 0, 0), "0 1 0", -1.0472, 2.0944),
    ("left_wrist_roll_joint", "left_elbow_link", "left_wrist_roll_link", (0.1, 0.00188791, -0.01), (0, 0, 0), "1 0 0", -1.972222054, 1.972222054),
    ("left_wrist_pitch_joint", "left_wrist_roll_link", "left_wrist_pitch_link", (0.038, 0, 0), (0, 0, 0), "0 1 0", -1.614429558, 1.614429558),
    ("left_wrist_yaw_joint", "left_wrist_pitch_link", "left_wrist_yaw_link", (0.046, 0, 0), (0, 0, 0), "0 0 1", -1.614429558, 1.614429558),
    ("right_shoulder_pitch_joint", "torso_link", "right_shoulder_pitch_link", (0.0039563, -0.10021, 0.23778), (-0.27931, 5.4949e-05, 0.00019159), "0 1 0", -3.0892, 2.6704),
    ("right_shoulder_roll_joint", "right_shoulder_pitch_link", "right_shoulder_roll_link", (0, -0.038, -0.013831), (0.27925, 0, 0), "1 0 0", -2.2515, 1.5882),
    ("right_shoulder_yaw_joint", "right_shoulder_roll_link", "right_shoulder_yaw_link", (0, -0.00624, -0.1032), (0, 0, 0), "0 0 1", -2.618, 2.618),
    ("right_elbow_joint", "right_shoulder_yaw_link", "right_elbow_link", (0.015783, 0, -0.080518), (0, 0, 0), "0 1 0", -1.0472, 2.0944),
    ("right_wrist_roll_joint", "right_elbow_link", "right_wrist_roll_link", (0.1, -0.00188791, -0.01), (0, 0, 0), "1 0 0", -1.972222054, 1.972222054),
    ("right_wrist_pitch_joint", "right_wrist_roll_link", "right_wrist_pitch_link", (0.038, 0, 0), (0, 0, 0), "0 1 0", -1.614429558, 1.614429558),
    ("right_wrist_yaw_joint", "right_wrist_pitch_link", "right_wrist_yaw_link", (0.046, 0, 0), (0, 0, 0), "0 0 1", -1.614429558, 1.614429558),
)
"""In Unitree's motor order: rt/lowstate's motor i drives JOINTS[i]."""
# fmt: on

DARK, LIGHT, ACCENT = "dark", "light", "accent"
COLOURS = {DARK: "0.22 0.23 0.25 1", LIGHT: "0.78 0.79 0.8 1", ACCENT: "0.2 0.45 0.8 1"}

# Extra solids per link: (kind, size, xyz, material); kind box (size x y z) or sphere (radius).
EXTRAS: dict[str, list[tuple[str, tuple[float, ...], tuple[float, ...], str]]] = {
    "pelvis": [("box", (0.1, 0.17, 0.09), (0.0, 0.0, -0.07), DARK)],
    "torso_link": [
        ("box", (0.13, 0.2, 0.24), (0.0, 0.0, 0.17), LIGHT),
        ("box", (0.04, 0.12, 0.08), (0.07, 0.0, 0.2), ACCENT),
        ("sphere", (0.075,), (0.01, 0.0, 0.43), DARK),
    ],
    "left_ankle_roll_link": [("box", (0.2, 0.07, 0.03), (0.035, 0.0, -0.03), DARK)],
    "right_ankle_roll_link": [("box", (0.2, 0.07, 0.03), (0.035, 0.0, -0.03), DARK)],
    "left_wrist_yaw_link": [("box", (0.1, 0.03, 0.07), (0.07, 0.0, 0.0), DARK)],
    "right_wrist_yaw_link": [("box", (0.1, 0.03, 0.07), (0.07, 0.0, 0.0), DARK)],
}
BONE_RADIUS_M = {"hip": 0.04, "knee": 0.035, "shoulder": 0.03, "elbow": 0.025, "wrist": 0.022}
MIN_BONE_M = 0.02


def _radius(link: str) -> float:
    for word, radius in BONE_RADIUS_M.items():
        if word in link:
            return radius
    return 0.03


def _bone_rpy(dx: float, dy: float, dz: float) -> tuple[float, float, float]:
    """rpy turning z onto the direction (dx, dy, dz) (URDF: R = Rz(y) Ry(p) Rx(r), r = 0)."""
    length = math.sqrt(dx * dx + dy * dy + dz * dz)
    pitch = math.acos(max(-1.0, min(1.0, dz / length)))
    yaw = math.atan2(dy, dx)
    return 0.0, pitch, yaw


def _f(values: tuple[float, ...]) -> str:
    return " ".join(f"{v:.6g}" for v in values)


def _visual(shape: str, xyz: tuple[float, ...], rpy: tuple[float, ...], material: str) -> str:
    return (
        f'    <visual>\n      <origin xyz="{_f(xyz)}" rpy="{_f(rpy)}"/>\n'
        f"      <geometry>{shape}</geometry>\n"
        f'      <material name="{material}"/>\n    </visual>\n'
    )


def urdf() -> str:
    """The URDF text."""
    links = ["pelvis"] + [j[2] for j in JOINTS]
    children: dict[str, list[tuple[float, ...]]] = {link: [] for link in links}
    for _name, parent, _child, xyz, *_rest in JOINTS:
        children[parent].append(xyz)
    out = [
        "<?xml version='1.0'?>\n",
        "<!-- Generated by scripts/make_g1_urdf.py: Unitree's g1_29dof kinematics (BSD-3-Clause,\n"
        "     Unitree Robotics; see g1_29dof.LICENSE) drawn with primitives. Do not edit. -->\n",
        '<robot name="g1_29dof">\n',
    ]
    out += [
        f'  <material name="{name}"><color rgba="{rgba}"/></material>\n'
        for name, rgba in COLOURS.items()
    ]
    for link in links:
        out.append(f'  <link name="{link}">\n')
        material = DARK if "hip_pitch" in link or "ankle" in link else LIGHT
        for dx, dy, dz in children[link]:
            length = math.sqrt(dx * dx + dy * dy + dz * dz)
            if length < MIN_BONE_M:
                continue
            shape = f'<cylinder radius="{_radius(link):.3g}" length="{length:.6g}"/>'
            mid = (dx / 2, dy / 2, dz / 2)
            out.append(_visual(shape, mid, _bone_rpy(dx, dy, dz), material))
        for kind, size, xyz, extra_material in EXTRAS.get(link, []):
            if kind == "box":
                shape = f'<box size="{_f(size)}"/>'
            else:
                shape = f'<sphere radius="{size[0]:.6g}"/>'
            out.append(_visual(shape, xyz, (0.0, 0.0, 0.0), extra_material))
        if "shoulder_pitch" in link or "hip_roll" in link:  # a joint housing
            shape = f'<sphere radius="{_radius(link) * 1.3:.3g}"/>'
            out.append(_visual(shape, (0.0, 0.0, 0.0), (0.0, 0.0, 0.0), DARK))
        out.append("  </link>\n")
    for name, parent, child, xyz, rpy, axis, lower, upper in JOINTS:
        out.append(
            f'  <joint name="{name}" type="revolute">\n'
            f'    <origin xyz="{_f(xyz)}" rpy="{_f(rpy)}"/>\n'
            f'    <parent link="{parent}"/>\n    <child link="{child}"/>\n'
            f'    <axis xyz="{axis}"/>\n'
            f'    <limit lower="{lower:.6g}" upper="{upper:.6g}" effort="0" velocity="0"/>\n'
            "  </joint>\n"
        )
    out.append("</robot>\n")
    return "".join(out)


if __name__ == "__main__":
    OUT.write_text(urdf())
    sys.stdout.write(f"wrote {OUT}\n")
