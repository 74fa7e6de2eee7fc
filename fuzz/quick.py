"""A short mutation run of every fuzz target without atheris (``make test``, a few seconds each).

``make fuzz`` is the long, coverage-guided run (atheris, optional). This one keeps the targets
true to the product between those runs: it replays each target's seeds and then feeds ``check``
mutations of them (byte flips, JSON and TOML tokens, cuts, repeats, splices of two seeds) for
``seconds``, deterministically (a fixed random seed). A stale invariant (issue 28: the inventory
target asserted that every inventory has arms after devices-only inventories became valid)
fails ``make test`` instead of rotting until the next long run.

    python -m fuzz.quick [--seconds 3] [TARGET ...]
"""

from __future__ import annotations

import argparse
import importlib
import random
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass

from fuzz import TARGETS
from fuzz.run import EXTRA_TOKENS

QUICK_SECONDS = 3.0
TOKENS = (
    *EXTRA_TOKENS,
    *(b"{", b"}", b"[", b"]", b",", b":", b'"', b"=", b"\n[", b"]\n", b"0", b"-1", b"1e9"),
    *(b'"op"', b'"devices"', b"[grippers.x]\n", b"[g1.y]\n", b"[arms.z]\n", b'mount = "a1"\n'),
)


@dataclass
class QuickResult:
    """One target's run: inputs tried, and the first failure (input, error) if any."""

    target: str
    inputs: int
    failure: tuple[bytes, str] | None = None


def mutate(rng: random.Random, data: bytes, other: bytes) -> bytes:
    """One to four random edits of ``data`` (``other``: a second seed to splice in)."""
    out = bytearray(data)
    for _ in range(rng.randint(1, 4)):
        choice = rng.randrange(6)
        at = rng.randint(0, len(out))
        if choice == 0 and out:
            out[min(at, len(out) - 1)] ^= 1 << rng.randrange(8)
        elif choice == 1:
            out[at:at] = rng.choice(TOKENS)
        elif choice == 2:
            del out[at : at + rng.randint(1, 16)]
        elif choice == 3:
            out[at:at] = out[at : at + rng.randint(1, 32)] * rng.randint(1, 4)
        elif choice == 4:
            cut = rng.randint(0, len(other))
            out = out[:at] + other[cut:]
        else:
            out[at:at] = bytes([rng.randrange(256)])
    return bytes(out[:8192])


def run_target(target: str, seconds: float, seed: int = 28) -> QuickResult:
    """Seeds, then mutations of them for ``seconds``; stops at the first failure."""
    module = importlib.import_module(f"fuzz.{target}")
    check: Callable[[bytes], None] = module.check
    seeds: list[bytes] = module.seeds()
    rng = random.Random(seed)
    result = QuickResult(target, 0)
    deadline = time.monotonic() + seconds
    queue = list(seeds)
    while True:
        data = queue.pop() if queue else mutate(rng, rng.choice(seeds), rng.choice(seeds))
        result.inputs += 1
        try:
            check(data)
        except Exception as exc:  # noqa: BLE001 - any escape breaks the target's property
            result.failure = (data, f"{type(exc).__name__}: {str(exc)[:300]}")
            return result
        if not queue and time.monotonic() >= deadline:
            return result


def main() -> int:
    """Run the targets; exit 1 when any failed."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=QUICK_SECONDS)
    parser.add_argument("targets", nargs="*", default=list(TARGETS))
    args = parser.parse_args()
    failed = 0
    for target in args.targets:
        result = run_target(target, args.seconds)
        status = "ok" if result.failure is None else f"FAILED: {result.failure[1]}"
        print(f"{target:12} {result.inputs:8} inputs  {status}")
        if result.failure is not None:
            print(f"  input: {result.failure[0][:400]!r}")
            failed += 1
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
