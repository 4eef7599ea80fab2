#!/usr/bin/env python3
"""Collects `summary.json` files of `anerf eval` into one Markdown table shaped like the paper's.

Usage: collect.py --title "Frames" label=path/to/summary.json [label=... ...]
"""
import argparse
import json


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--title", required=True)
    parser.add_argument("rows", nargs="+", help="label=summary.json")
    args = parser.parse_args()
    lines = [f"| {args.title} | PSNR | SSIM | images |", "|---|---:|---:|---:|"]
    for row in args.rows:
        label, path = row.split("=", 1)
        with open(path) as f:
            s = json.load(f)
        lines.append(f"| {label} | {float(s['psnr']):.2f} | {float(s['ssim']):.3f} | {s['images']} |")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
