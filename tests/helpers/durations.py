"""Sum a ``--durations-log`` file: where the suite's time goes, and what bounds its wall time.

``python -m pytest -n 4 --dist loadgroup --durations-log=/tmp/d.tsv`` writes one line per test
phase (worker, node id, phase, seconds, outcome; ``tests/conftest.py``);
``python -m tests.helpers.durations /tmp/d.tsv [--top N]`` prints the totals per phase, per
worker, per ``SHARED_RESOURCE_GROUPS`` group and per file, the slowest tests, and the estimated
wall time of ``make test`` (four workers on two cores): the larger of the longest group (a
group runs on one worker, one test after another) and the durations outside the waiting groups
(the LinuxCNC groups, which mostly wait on their simulator's real time) over the two cores.
With more workers than cores every test's duration is stretched by the CPU the others take,
so the estimate runs high (771 s for a four-worker run of 585 s); the CPU seconds of a run
(``/proc/stat``) over the cores are the floor.  Compare two runs file by file: on a shared
box both runs' durations swing with the load, so compare files measured side by side.
"""

from __future__ import annotations

import argparse
import sys
from collections import Counter
from pathlib import Path

from tests.conftest import shared_resource_group

CORES = 2  # `make test`: -n 4, the LinuxCNC groups' workers mostly waiting
WAITING_GROUPS = "linuxcnc"  # the prefix of the LinuxCNC groups' names


def read(path: Path) -> list[tuple[str, str, str, float, str]]:
    """The log's rows: (worker, node id, phase, seconds, outcome)."""
    rows = []
    for line in path.read_text(encoding="utf-8").splitlines():
        worker, nodeid, when, seconds, outcome = line.split("\t")
        rows.append((worker, nodeid, when, float(seconds), outcome))
    return rows


def main(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("log", type=Path)
    parser.add_argument("--top", type=int, default=30)
    args = parser.parse_args(argv)
    rows = read(args.log)
    per_phase: Counter[str] = Counter()
    per_worker: Counter[str] = Counter()
    per_group: Counter[str] = Counter()
    per_file: Counter[str] = Counter()
    per_test: Counter[str] = Counter()
    failed = sorted({nodeid for _, nodeid, _, _, outcome in rows if outcome == "failed"})
    for worker, nodeid, when, seconds, _ in rows:
        per_phase[when] += seconds
        per_worker[worker] += seconds
        per_group[shared_resource_group(nodeid) or "(no group)"] += seconds
        per_file[nodeid.split("::")[0]] += seconds
        per_test[nodeid] += seconds
    total = sum(per_phase.values())
    longest = max((s for g, s in per_group.items() if g != "(no group)"), default=0.0)
    print(f"{len(per_test)} tests, {total:.0f} s of test durations (setup + call + teardown)")
    print("per phase:  " + ", ".join(f"{k} {v:.0f} s" for k, v in per_phase.most_common()))
    print("per worker: " + ", ".join(f"{k} {v:.0f} s" for k, v in sorted(per_worker.items())))
    print("per group:  " + ", ".join(f"{k} {v:.0f} s" for k, v in per_group.most_common()))
    busy = (total - sum(s for g, s in per_group.items() if g.startswith(WAITING_GROUPS))) / CORES
    print(f"estimated wall on {CORES} cores (collection not included): {max(busy, longest):.0f} s = "
          f"max(durations outside {WAITING_GROUPS}* / {CORES} {busy:.0f} s, longest group {longest:.0f} s)")
    print(f"--- slowest files (of {len(per_file)})")
    for name, seconds in per_file.most_common(args.top):
        print(f"{seconds:8.1f} s  {name}")
    print("--- slowest tests")
    for name, seconds in per_test.most_common(args.top):
        print(f"{seconds:8.1f} s  {name}")
    if failed:
        print("--- failed: " + ", ".join(failed))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
