"""Fuzz target: the choreography parser (``fleet/choreo/script.py`` ``parse_script``), and what
``fleet play`` does with a script that parses.

Property: any text gives a ``Script`` or ``ScriptError``, never another exception; a script
that ``check_motion`` accepts, played on the timeline from a zero pose, never asks an arm for
a target outside its joint ranges (a D1's, or a G1 arm's own) or faster than the script's
``max_speed_deg_s``.
"""

from __future__ import annotations

from fuzz.common import instrumented, main, toml_text

with instrumented():
    from fleet.choreo.script import ScriptError, parse_script
    from fleet.choreo.timeline import ArmFacts, Timeline
    from fleet.choreo.validate import check_motion, default_ranges

ARMS = ("a1", "a2", "a3")
GROUPS = {"left": ("a1", "a2")}
G1S = ("h1",)
"""A G1 whose arms (``h1.left``, ``h1.right``) a script may name beside the D1 arms."""
ZERO = (0.0,) * 7
TICKS = 200
"""Frames sampled per input (at least 50 ms apart): enough to cross every step of a short
script, few enough to keep a run fast."""


def check(data: bytes) -> None:
    """The property, for one input."""
    try:
        script = parse_script(toml_text(data), "fuzz.toml", ARMS, GROUPS, G1S)
    except ScriptError:
        return
    start = dict.fromkeys(script.arms, ZERO)
    try:
        check_motion(script, start)
    except ScriptError:
        return
    _play(script, start)


def _play(script, start) -> None:  # type: ignore[no-untyped-def]
    """Tick the timeline with every arm on its target and every grip confirmed."""
    passes = 1 if script.loops == 1 else 2
    dt = max(0.05, passes * (script.iteration_s + 1.0) / TICKS)
    timeline = Timeline(script, start)
    timeline.start(0.0)
    last = dict(start)
    for tick in range(1, TICKS + 1):
        facts = {arm: ArmFacts(angles_deg=pose, gripped=True) for arm, pose in last.items()}
        frame = timeline.tick(tick * dt, facts)
        for arm, pose in frame.targets.items():
            for joint, (angle, (low, high)) in enumerate(zip(pose, default_ranges(arm))):
                assert low - 1e-9 <= angle <= high + 1e-9, (arm, joint, angle, frame)
                step = abs(angle - last[arm][joint])
                assert step <= script.max_speed_deg_s * dt * (1 + 1e-9) + 1e-9, (
                    arm,
                    joint,
                    step / dt,
                    frame,
                )
        last = dict(frame.targets)
        if frame.kind in ("done", "failed"):
            return


def seeds() -> list[bytes]:
    """``choreo/demo.toml`` and the tests' choreography."""
    from fuzz.common import REPO
    from testkit.file_tables import choreo_text

    demo = (REPO / "choreo" / "demo.toml").read_text(encoding="utf-8")
    return [demo.encode(), choreo_text({}).encode()]


if __name__ == "__main__":
    main(check)
