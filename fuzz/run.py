"""Run the fuzz targets under atheris, each for a time budget, and print a summary table.

    python -m fuzz.run [--seconds 60] [--timeout 10] [TARGET ...]     (``make fuzz``)

Per target: the seed corpus (``seeds()``) is written to ``artifacts/fuzz/seeds/<target>/``;
libFuzzer grows the working corpus in ``artifacts/fuzz/corpus/<target>/`` (kept between runs)
and writes any failing input to ``artifacts/fuzz/crashes/<target>/`` (``crash-*``: the property
broke or an exception escaped; ``timeout-*``: one input ran longer than ``--timeout`` seconds, a
hang). libFuzzer stops at the first failure; the runner then starts the target again for the
rest of its budget (at most ``MAX_RUNS`` times), so one cheap crash does not end the run.
The log of each target is ``artifacts/fuzz/logs/<target>.log``. Exit code 1 when any target
crashed or hung, 0 otherwise.
"""

from __future__ import annotations

import argparse
import importlib
import json
import os
import re
import signal
import subprocess
import sys
import time
from dataclasses import asdict, dataclass
from pathlib import Path

from fuzz import TARGETS
from fuzz.common import REPO

OUT = REPO / "artifacts" / "fuzz"
MAX_RUNS = 20
"""Restarts of one target after failures, within its budget."""
MAX_LEN = 8192
"""Longest input libFuzzer makes: twice the 4 KiB cap of most payloads and of D1 strings."""
GRACE_S = 60.0
"""How much longer than its budget a target may take to stop before it is killed by PID."""

_EXECUTED = re.compile(r"stat::number_of_executed_units:\s*(\d+)")
_PROGRESS = re.compile(r"^#(\d+)\s", re.MULTILINE)


@dataclass
class Result:
    """One target's totals over all its runs."""

    target: str
    executions: int = 0
    seconds: float = 0.0
    crashes: int = 0
    hangs: int = 0
    runs: int = 0
    corpus: int = 0
    failures: list[str] | None = None


def _budget_from_env() -> float:
    return float(os.environ.get("FUZZ_SECONDS") or 60)


def write_seeds(target: str) -> tuple[Path, Path]:
    """The target's seed corpus as files (fresh each run), and its dictionary."""
    directory = OUT / "seeds" / target
    directory.mkdir(parents=True, exist_ok=True)
    for old in directory.iterdir():
        old.unlink()
    module = importlib.import_module(f"fuzz.{target}")
    seeds: list[bytes] = module.seeds()
    for index, seed in enumerate(seeds):
        (directory / f"seed-{index:03d}").write_bytes(seed)
    return directory, write_dictionary(target, seeds)


_QUOTED = re.compile(rb'"[^"\\\n]{1,40}"')
_WORD = re.compile(rb"[A-Za-z_][A-Za-z0-9_]{1,40}")
EXTRA_TOKENS = (
    *(b"NaN", b"Infinity", b"-0", b"1e400", b"-1e308", b"nan", b"inf", b"true", b"null"),
    *(b"\\u0000", b"\\u0001", b"\\b", b"\\f", b"\\n", b"\\t", b"\\ud800", b"\\U0010ffff"),
)
"""Values that broke decoders before (non-finite literals, overflowing numbers) and the escapes
that put control characters and odd code points into JSON and TOML strings."""


def write_dictionary(target: str, seeds: list[bytes]) -> Path:
    """A libFuzzer dictionary: every quoted string and word of the seeds (field names, ops,
    tags, TOML keys) and a few hostile literals, so mutations speak the format."""
    tokens: set[bytes] = set(EXTRA_TOKENS)
    for seed in seeds:
        tokens.update(_QUOTED.findall(seed))
        tokens.update(_WORD.findall(seed))
    path = OUT / "seeds" / f"{target}.dict"
    lines = []
    for token in sorted(tokens)[:1000]:
        escaped = "".join(
            chr(b) if 32 <= b < 127 and b not in b'"\\' else f"\\x{b:02x}" for b in token
        )
        lines.append(f'"{escaped}"')
    path.write_text("\n".join(lines) + "\n", encoding="ascii")
    return path


def _failures(directory: Path) -> set[str]:
    return {
        f.name for f in directory.iterdir() if f.name.startswith(("crash-", "timeout-", "oom-"))
    }


def _executions(text: str) -> int:
    """Executions libFuzzer reported: its final stats, else its last progress line."""
    found = _EXECUTED.findall(text)
    if found:
        return int(found[-1])
    progress = _PROGRESS.findall(text)
    return int(progress[-1]) if progress else 0


def run_target(target: str, budget_s: float, timeout_s: int) -> Result:
    """Fuzz ``target`` for ``budget_s`` seconds in total (restarting after failures)."""
    corpus = OUT / "corpus" / target
    crashes = OUT / "crashes" / target
    for directory in (corpus, crashes, OUT / "logs"):
        directory.mkdir(parents=True, exist_ok=True)
    seeds, dictionary = write_seeds(target)
    log_path = OUT / "logs" / f"{target}.log"
    log_path.write_text("")
    result = Result(target)
    before = _failures(crashes)
    started = time.monotonic()
    while result.runs < MAX_RUNS:
        left = budget_s - (time.monotonic() - started)
        if left < 1.0:
            break
        result.runs += 1
        argv = [
            sys.executable,
            "-m",
            f"fuzz.{target}",
            f"-max_total_time={max(1, int(left))}",
            f"-timeout={timeout_s}",
            f"-max_len={MAX_LEN}",
            f"-artifact_prefix={crashes}/",
            f"-dict={dictionary}",
            "-print_final_stats=1",
            str(corpus),
            str(seeds),
        ]
        text = _run(argv, left + GRACE_S, log_path)
        result.executions += _executions(text)
    result.seconds = round(time.monotonic() - started, 1)
    new = sorted(_failures(crashes) - before)
    result.crashes = sum(1 for name in new if not name.startswith("timeout-"))
    result.hangs = sum(1 for name in new if name.startswith("timeout-"))
    result.failures = [str(crashes / name) for name in new]
    result.corpus = sum(1 for _ in corpus.iterdir())
    return result


def _run(argv: list[str], limit_s: float, log_path: Path) -> str:
    """Run one libFuzzer session; its output is appended to the log and returned. A session
    that outlives ``limit_s`` is killed by its PID (its process group: atheris forks none, but
    a hung interpreter must not survive the runner)."""
    env = {**os.environ, "FUZZ_INSTRUMENT": "1", "PYTHONPATH": str(REPO)}
    with open(log_path, "a", encoding="utf-8") as log:
        log.write(f"$ {' '.join(argv[2:])}\n")
        log.flush()
        start = log.tell()
        process = subprocess.Popen(
            argv, stdout=log, stderr=subprocess.STDOUT, env=env, cwd=REPO, start_new_session=True
        )
        try:
            process.wait(timeout=limit_s)
        except subprocess.TimeoutExpired:
            os.killpg(process.pid, signal.SIGKILL)
            process.wait(timeout=30)
            log.write(f"\nfuzz.run: killed after {limit_s:.0f} s\n")
    with open(log_path, encoding="utf-8", errors="replace") as log:
        log.seek(start)
        return log.read()


def table(results: list[Result]) -> str:
    """The summary as a Markdown table."""
    lines = [
        "| target | executions | seconds | exec/s | crashes | hangs | runs | corpus |",
        "|---|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for r in results:
        rate = r.executions / r.seconds if r.seconds else 0.0
        lines.append(
            f"| {r.target} | {r.executions:,} | {r.seconds:.0f} | {rate:,.0f} | {r.crashes} | "
            f"{r.hangs} | {r.runs} | {r.corpus} |"
        )
    total = sum(r.executions for r in results)
    seconds = sum(r.seconds for r in results)
    crashes = sum(r.crashes for r in results)
    hangs = sum(r.hangs for r in results)
    lines.append(f"| **all** | {total:,} | {seconds:.0f} | | {crashes} | {hangs} | | |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    """Command line: see the module docstring."""
    parser = argparse.ArgumentParser(prog="python -m fuzz.run", description=__doc__.split("\n")[0])
    parser.add_argument(
        "--seconds",
        type=float,
        default=_budget_from_env(),
        help="budget per target (default: $FUZZ_SECONDS or 60)",
    )
    parser.add_argument(
        "--timeout",
        type=int,
        default=int(os.environ.get("FUZZ_TIMEOUT") or 10),
        help="seconds one input may take before it counts as a hang (default 10)",
    )
    parser.add_argument("targets", nargs="*", metavar="TARGET", help=f"default: all of {TARGETS}")
    args = parser.parse_args(argv)
    unknown = sorted(set(args.targets) - set(TARGETS))
    if unknown:
        parser.error(
            f"unknown target(s) {', '.join(unknown)}; the targets are {', '.join(TARGETS)}"
        )
    targets = args.targets or list(TARGETS)
    load = os.getloadavg()
    print(
        f"fuzzing {len(targets)} targets, {args.seconds:g} s each; load {load[0]:.2f}", flush=True
    )
    results = []
    for target in targets:
        result = run_target(target, args.seconds, args.timeout)
        print(
            f"  {target}: {result.executions:,} executions in {result.seconds:.0f} s, "
            f"{result.crashes} crashes, {result.hangs} hangs",
            flush=True,
        )
        for path in result.failures or []:
            print(f"    {path}  (replay: python -m fuzz.{target} {path})", flush=True)
        results.append(result)
    summary = table(results)
    stamp = time.strftime("%Y-%m-%dT%H:%M:%S%z")
    end_load = os.getloadavg()
    footer = (
        f"{stamp}; {args.seconds:g} s per target, per-input timeout {args.timeout} s; "
        f"load average {load[0]:.2f} at start, {end_load[0]:.2f} at end"
    )
    print(f"\n{summary}\n\n{footer}")
    (OUT / "summary.md").write_text(f"{summary}\n\n{footer}\n", encoding="utf-8")
    data = {"stamp": stamp, "results": [asdict(r) for r in results], "load": [load, end_load]}
    (OUT / "summary.json").write_text(json.dumps(data, indent=1), encoding="utf-8")
    return 1 if any(r.crashes or r.hangs for r in results) else 0


if __name__ == "__main__":
    sys.exit(main())
