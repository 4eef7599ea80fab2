#!/usr/bin/env python3
"""Sums CubeCL's per-kernel profiling log into a table: time, launches and mean per kernel name, largest
first, with each name's share of the logged total.

CubeCL logs one line per profiled kernel, `| <duration> | <name>`, when profiling is on: run anerf with
`CUBECL_DEBUG_LOG=<file>` (which also logs compilation and autotuning into that file; the durations are
measured with a sync after each kernel, so they add up to more than the unprofiled step). Names are
shortened at their first '<' or '(' so that one kernel's launches with different shapes add up.

usage: kernel_profile.py LOG [--top N] [--full-names]
"""
import argparse
import collections
import re
import sys

LINE = re.compile(r"^\|\s*([0-9.]+)(ns|µs|us|ms|s)\s*\|\s*(.+)$")
SCALE = {"ns": 1e-9, "µs": 1e-6, "us": 1e-6, "ms": 1e-3, "s": 1.0}


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("log")
    parser.add_argument("--top", type=int, default=30)
    parser.add_argument("--full-names", action="store_true")
    args = parser.parse_args()
    total = collections.Counter()
    count = collections.Counter()
    with open(args.log, encoding="utf-8", errors="replace") as f:
        for line in f:
            m = LINE.match(line.strip())
            if not m:
                continue
            seconds = float(m.group(1)) * SCALE[m.group(2)]
            name = m.group(3).strip()
            if not args.full_names:
                name = re.split(r"[<(]", name, maxsplit=1)[0].strip()[:120]
            total[name] += seconds
            count[name] += 1
    grand = sum(total.values())
    if not grand:
        sys.exit(f"no profiled kernel in {args.log} (was CUBECL_DEBUG_LOG set?)")
    print(f"{'ms':>10} {'share':>6} {'launches':>8} {'mean us':>9}  kernel")
    for name, seconds in total.most_common(args.top):
        print(f"{seconds * 1e3:10.3f} {seconds / grand:6.1%} {count[name]:8d} "
              f"{seconds / count[name] * 1e6:9.1f}  {name}")
    print(f"{grand * 1e3:10.3f} 100.0% {sum(count.values()):8d}            all {len(total)} kernels")


if __name__ == "__main__":
    main()
