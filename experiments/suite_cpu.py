"""Per-test CPU time of the suite, for comparing two commits' suites test by test.

As a pytest plugin it appends one line per test to the file named by
``SUITE_CPU``: the file, the test and the process CPU seconds of its setup,
call and teardown. It needs nothing from the suite's own ``conftest.py``, so
it records any commit's suite alike. It appends, so start from no file. Run
each commit's suite in one process on one core from an empty compilation
cache::

    rm -rf .xla-cache && SUITE_CPU=/tmp/new.tsv PYTHONPATH=experiments \\
        taskset -c 0 python -m pytest -q -n 0 -p suite_cpu

(for another checkout, point ``PYTHONPATH`` at this folder). Then
``python experiments/suite_cpu.py OLD.tsv NEW.tsv`` splits the difference
into the tests both suites hold and the tests only one holds, per file.
"""

import collections
import csv
import os
import sys
import time

import pytest


@pytest.hookimpl(wrapper=True)
def pytest_runtest_protocol(item, nextitem):
    start = time.process_time()
    result = yield
    with open(os.environ["SUITE_CPU"], "a", encoding="utf-8") as record:
        record.write(f"{item.path.name}\t{item.name}\t{time.process_time() - start:.2f}\n")
    return result


def _load(path: str) -> dict[tuple[str, str], float]:
    record: dict[tuple[str, str], float] = {}
    with open(path, encoding="utf-8") as f:
        for file, test, cpu in csv.reader(f, delimiter="\t"):
            if (file, test) in record:
                raise SystemExit(f"{path} holds {file}::{test} twice: record each suite afresh")
            record[file, test] = float(cpu)
    return record


def compare(old: dict, new: dict) -> str:
    """Markdown: CPU seconds of the shared tests, then of each side's own tests per file."""
    shared = old.keys() & new.keys()
    lines = [
        "| tests | count | old CPU s | new CPU s |",
        "|---|---:|---:|---:|",
        f"| in both | {len(shared)} | {sum(old[k] for k in shared):.1f} | "
        f"{sum(new[k] for k in shared):.1f} |",
    ]
    for name, side, column in (("only new", new, 3), ("only old", old, 2)):
        own = side.keys() - shared
        lines.append(
            f"| {name} | {len(own)} | "
            + " | ".join(f"{sum(side[k] for k in own):.1f}" if c == column else "" for c in (2, 3))
            + " |"
        )
        per_file = collections.Counter()
        for key in own:
            per_file[key[0]] += side[key]
        lines += [
            f"| &nbsp; {file} | {sum(1 for k in own if k[0] == file)} | "
            + " | ".join(f"{cpu:.1f}" if c == column else "" for c in (2, 3))
            + " |"
            for file, cpu in per_file.most_common()
            if cpu >= 0.5
        ]
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    if len(sys.argv) != 3:
        raise SystemExit("usage: python experiments/suite_cpu.py OLD.tsv NEW.tsv")
    print(compare(_load(sys.argv[1]), _load(sys.argv[2])), end="")
