#!/usr/bin/env python3
"""Numpy checks behind docs/QUALITY.md's sections on the mask-edge band (issue 35), on subjects `anerf synth`
wrote.

  silhouette_checks.py fill <subject> [--masks <subject>] [--camera Camera_B1] [--frames 60]
      How much of the mask-edge band has a known background under `train.mask_edges = "backdrop"` (the
      median over the frames whose mask, dilated by the margin, leaves a pixel uncovered, known where at
      least 3 do; as crates/anerf-data/src/sampler/background.rs), how much within R px of a known pixel,
      and how far three ways of filling the unknown pixels are from the colours the frames show there with
      a 1 px margin: the nearest known pixel (what anerf does), a push-pull pyramid, an onion peel.
      --masks reads the masks of another subject (e.g. the same images' noisy masks).

  silhouette_checks.py boundary <subject> [--frames 90]
      The synthetic masks mark every pixel whose square touches the body (conservative coverage), so their
      pixel count exceeds the silhouette's continuous area by about half a pixel per boundary pixel: the
      area ratio a perfectly soft render would score is about 1 - boundary / (2 area).

  silhouette_checks.py rings <subject> <run> [--split novel-view]
      Where the band's error lies in a run's evaluated images (`anerf eval` writes them): the PSNR of each
      ring of pixels at 1 and 2 px inside and outside the subject's true silhouette (the band `eval`
      reports is their union), their mean signed error (prediction - truth) and share of the band's
      squared error.
"""
import argparse
import os
import re
import warnings

import numpy as np
from PIL import Image
from scipy import ndimage as ndi


def square(r):
    return np.ones((2 * r + 1, 2 * r + 1), bool)


def read(subject, masks, camera, frames):
    images = np.stack([np.asarray(Image.open(f"{subject}/{camera}/{f:06d}.jpg"), np.float32) / 255
                       for f in frames])
    sets = np.stack([np.asarray(Image.open(f"{masks}/mask_cihp/{camera}/{f:06d}.png")) > 0 for f in frames])
    return images, sets


def median_over(images, uncovered):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # pixels no frame leaves uncovered
        return np.nan_to_num(np.nanmedian(np.where(uncovered[..., None], images, np.nan), 0))


def push_pull(colours, weights):
    h, w = weights.shape
    if min(h, w) <= 1:
        return colours
    H, W = (h + 1) // 2 * 2, (w + 1) // 2 * 2
    c = np.zeros((H, W, 3))
    k = np.zeros((H, W))
    c[:h, :w], k[:h, :w] = colours * weights[..., None], weights
    cs, ks = c.reshape(H // 2, 2, W // 2, 2, 3).sum((1, 3)), k.reshape(H // 2, 2, W // 2, 2).sum((1, 3))
    coarse = push_pull(np.where(ks[..., None] > 0, cs / np.maximum(ks, 1e-9)[..., None], 0), np.minimum(ks, 1))
    return np.where(weights[..., None] > 0, colours, coarse.repeat(2, 0).repeat(2, 1)[:h, :w])


def onion(colours, known, rounds):
    colours, known = colours.copy(), known.copy()
    for _ in range(rounds):
        k = known.astype(np.float64)
        total = ndi.convolve(colours * k[..., None], np.ones((3, 3, 1)), mode="constant")
        count = ndi.convolve(k, np.ones((3, 3)), mode="constant")
        new = ~known & (count > 0)
        colours[new] = total[new] / count[new][:, None]
        known |= new
    return colours, known


def fill(args):
    frames = range(args.frames)
    images, masks = read(args.subject, args.masks or args.subject, args.camera, frames)
    band = np.stack([ndi.binary_dilation(m, square(2)) & ~ndi.binary_erosion(m, square(2)) for m in masks])
    for margin in (4, 3, 2):
        known = np.stack([~ndi.binary_dilation(m, square(margin)) for m in masks]).sum(0) >= 3
        distance = ndi.distance_transform_edt(~known)
        within = " ".join(f"{r} px: {(band & (distance <= r)).sum() / band.sum():.3f}" for r in (2, 4, 8, 16))
        print(f"margin {margin}: band known {(band & known).sum() / band.sum():.3f}; within {within}")
    uncovered = np.stack([~ndi.binary_dilation(m, square(4)) for m in masks])
    known = uncovered.sum(0) >= 3
    plate = median_over(images, uncovered).astype(np.float64)
    seen = np.stack([~ndi.binary_dilation(m, square(1)) for m in masks])
    truth, checkable = median_over(images, seen), ~known & seen.any(0)
    nearest_at = ndi.distance_transform_edt(~known, return_distances=False, return_indices=True)
    nearest = plate[nearest_at[0], nearest_at[1]]
    pyramid = push_pull(plate, known.astype(np.float64))
    distance = ndi.distance_transform_edt(~known)
    for r in (4, 8):
        peeled, reached = onion(plate, known, r)
        pixels = checkable & (distance <= r) & reached
        error = lambda c: np.abs(c - truth)[pixels].mean()
        print(f"unknown pixels within {r} px ({pixels.sum()}): mean absolute error per channel: "
              f"nearest {error(nearest):.4f}, push-pull {error(pyramid):.4f}, onion peel {error(peeled):.4f}")


def boundary(args):
    counts = []
    for camera in ("Camera_B2", "Camera_B4", "Camera_B6", "Camera_B8"):
        for f in range(0, args.frames, 15):
            m = np.asarray(Image.open(f"{args.subject}/mask_cihp/{camera}/{f:06d}.png")) > 0
            counts.append(((m & ~ndi.binary_erosion(m)).sum(), m.sum()))
    b, a = np.array(counts).sum(0)
    print(f"boundary / area {b / a:.4f}: a perfectly soft render's area ratio is about {1 - b / a / 2:.3f}")


def rings(args):
    names = ("inside, 1 px", "inside, 2 px", "outside, 1 px", "outside, 2 px")
    totals = {name: np.zeros(3) for name in names}  # squared error, signed error, pixels
    pattern = re.compile(r"frame(\d+)_view(\d+)_gt\.png$")
    folder = f"{args.run}/eval/{args.split}/images"
    for name in sorted(os.listdir(folder)):
        found = pattern.search(name)
        if not found:
            continue
        frame, view = map(int, found.groups())
        truth = np.asarray(Image.open(f"{folder}/{name}"), np.float64)[..., :3] / 255
        drawn = np.asarray(Image.open(f"{folder}/{name[:-len('gt.png')]}pred.png"), np.float64)[..., :3] / 255
        # `anerf synth` names view v's folder Camera_B<v + 1> (crates/anerf-data/src/synthetic/layout.rs).
        mask = np.asarray(Image.open(f"{args.subject}/mask_cihp/Camera_B{view + 1}/{frame:06d}.png")) > 0
        inner1 = mask & ~ndi.binary_erosion(mask, square(1))
        inner2 = mask & ~ndi.binary_erosion(mask, square(2)) & ~inner1
        outer1 = ndi.binary_dilation(mask, square(1)) & ~mask
        outer2 = ndi.binary_dilation(mask, square(2)) & ~mask & ~outer1
        squared, signed = ((drawn - truth) ** 2).mean(-1), (drawn - truth).mean(-1)
        for ring, pixels in zip(names, (inner1, inner2, outer1, outer2)):
            totals[ring] += (squared[pixels].sum(), signed[pixels].sum(), pixels.sum())
    band = sum(t[0] for t in totals.values())
    for ring, (squared, signed, count) in totals.items():
        print(f"{ring}: {int(count)} pixels, PSNR {-10 * np.log10(squared / count):.2f} dB, "
              f"mean error {signed / count:+.4f}, share of the band's squared error {squared / band:.2f}")


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = parser.add_subparsers(dest="check", required=True)
    f = sub.add_parser("fill")
    f.add_argument("subject")
    f.add_argument("--masks")
    f.add_argument("--camera", default="Camera_B1")
    f.add_argument("--frames", type=int, default=60)
    b = sub.add_parser("boundary")
    b.add_argument("subject")
    b.add_argument("--frames", type=int, default=90)
    r = sub.add_parser("rings")
    r.add_argument("subject")
    r.add_argument("run")
    r.add_argument("--split", default="novel-view")
    args = parser.parse_args()
    {"fill": fill, "boundary": boundary, "rings": rings}[args.check](args)


if __name__ == "__main__":
    main()
