#!/usr/bin/env python3
"""Collects `anerf eval` summaries into one Markdown table shaped like the paper's.

Usage: collect.py --title "Frames" label=path/to/summary.json [label=... ...]
   or: collect.py --title "Variant" label=path/to/run [label=... ...]
A run folder gives one row with every split it was evaluated on (training-view, novel-view, novel-pose) side
by side, and the gap from the training views to the held-out views. With --silhouette, a second table gives
each split's PSNR in the 2-pixel band around the true silhouette, outside it, and the predicted silhouette's
area over the true one (`anerf eval`'s silhouette figures).
"""
import argparse
import json
import os

SPLITS = ["training-view", "novel-view", "novel-pose"]


def summary(path):
    with open(path) as f:
        return json.load(f)


def run_row(label, run):
    cells = [label]
    found = {}
    for split in SPLITS:
        path = os.path.join(run, "eval", split, "summary.json")
        if os.path.isfile(path):
            found[split] = summary(path)
            cells += [f"{float(found[split]['psnr']):.2f}", f"{float(found[split]['ssim']):.3f}"]
        else:
            cells += ["–", "–"]
    if "training-view" in found and "novel-view" in found:
        gap = float(found["training-view"]["psnr"]) - float(found["novel-view"]["psnr"])
        cells.append(f"{gap:.2f}")
    else:
        cells.append("–")
    return "| " + " | ".join(cells) + " |"


def silhouette_row(label, run):
    cells = [label]
    for split in SPLITS:
        path = os.path.join(run, "eval", split, "summary.json")
        s = summary(path) if os.path.isfile(path) else {}
        if "band_psnr" in s:
            cells += [f"{float(s['band_psnr']):.2f}", f"{float(s['outside_band_psnr']):.2f}",
                      f"{float(s['area_ratio']):.3f}"]
        else:
            cells += ["–", "–", "–"]
    return "| " + " | ".join(cells) + " |"


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--title", required=True)
    parser.add_argument("--silhouette", action="store_true", help="also the silhouette table (run folders)")
    parser.add_argument("rows", nargs="+", help="label=summary.json or label=run folder")
    args = parser.parse_args()
    rows = [row.split("=", 1) for row in args.rows]
    if all(os.path.isdir(path) for _, path in rows):
        head = " | ".join(f"{s} PSNR | {s} SSIM" for s in SPLITS)
        lines = [f"| {args.title} | {head} | gap (dB) |", "|---" + "|---:" * 7 + "|"]
        lines += [run_row(label, path) for label, path in rows]
        if args.silhouette:
            head = " | ".join(f"{s} band | {s} rest | {s} area" for s in SPLITS)
            lines += ["", f"| {args.title} | {head} |", "|---" + "|---:" * 9 + "|"]
            lines += [silhouette_row(label, path) for label, path in rows]
    else:
        lines = [f"| {args.title} | PSNR | SSIM | images |", "|---|---:|---:|---:|"]
        for label, path in rows:
            s = summary(path)
            lines.append(f"| {label} | {float(s['psnr']):.2f} | {float(s['ssim']):.3f} | {s['images']} |")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
