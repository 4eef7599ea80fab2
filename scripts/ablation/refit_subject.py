#!/usr/bin/env python3
"""A copy of a subject whose training frames carry a run's refined body fits instead of the given ones.

Usage: refit_subject.py <subject folder> <run folder> <new subject folder>

Reads `<run>/refined_poses.json` (written after stage 1 where the run refines its fits) and writes the new
folder: every file of the subject hard-linked (nothing is copied or changed in the original), except each
refined frame's `new_params/<i>.npy` (its `poses`, `Rh`, `Th` replaced by the refined fit; `shapes` kept) and
`new_vertices/<i>.npy` (linear blend skinning of `lbs/` with the refined fit, as the datasets pose their
vertices). Training on the new folder asks what a fresh model makes of fits that are already refined: the
second pass of docs/POSE-REFINEMENT.md, "A floor the schedule does not move". numpy only; the new folder
must not exist yet nor lie inside the subject, and is written whole or not at all (built under a
`.partial-<pid>` name beside it, which a failure removes).
"""
import json
import os
import shutil
import sys

import numpy as np

from pose_error import load_lbs, pose_of, posed_vertices


def replace(path, write):
    """Writes a fresh file at `path`, a hard link to the original's data until now."""
    os.unlink(path)
    write(path)


def frame_of(entry, frames_dir):
    """The entry's frame number (a name inside `frames_dir` only: a whole number, no path), its file there
    checked to exist."""
    frame = entry.get("frame")
    if not isinstance(frame, int) or isinstance(frame, bool) or frame < 0:
        sys.exit(f"refined_poses.json: frame {frame!r} is not a frame number")
    if not os.path.isfile(os.path.join(frames_dir, f"{frame}.npy")):
        sys.exit(f"refined_poses.json: frame {frame} has no {frames_dir}/{frame}.npy")
    return frame


def refit(subject, frames, out):
    """Fills the new folder `out` (a hard-linked copy of `subject`) with the refined fits."""
    lbs = load_lbs(subject)
    shutil.copytree(subject, out, copy_function=os.link)
    for entry in frames:
        frame = frame_of(entry, os.path.join(subject, "new_params"))
        joints, rh, th = pose_of(entry["refined"])
        params_path = os.path.join(out, "new_params", f"{frame}.npy")
        params = np.load(params_path, allow_pickle=True).item()
        params.update(poses=joints.reshape(1, -1), Rh=rh.reshape(1, 3), Th=th.reshape(1, 3))
        replace(params_path, lambda p: np.save(p, params))
        vertices = posed_vertices(lbs, joints, rh, th).astype(np.float32)
        replace(os.path.join(out, "new_vertices", f"{frame}.npy"), lambda p: np.save(p, vertices))


def main(args):
    if len(args) != 3:
        sys.exit(__doc__)
    subject, run, out = args
    if os.path.lexists(out):
        sys.exit(f"{out} exists: name a new folder")
    inside = os.path.commonpath([os.path.realpath(subject), os.path.realpath(out)])
    if inside == os.path.realpath(subject):
        sys.exit(f"{out} lies inside the subject {subject}: name a folder outside it")
    with open(os.path.join(run, "refined_poses.json")) as f:
        frames = json.load(f)
    # Written beside `out` and renamed once whole, so a failure leaves no half-written subject.
    partial = f"{out.rstrip(os.sep)}.partial-{os.getpid()}"
    try:
        refit(subject, frames, partial)
        os.rename(partial, out)
    except BaseException:
        shutil.rmtree(partial, ignore_errors=True)
        raise
    print(f"wrote {out}: {len(frames)} frames refit from {run}")


if __name__ == "__main__":
    main(sys.argv[1:])
