#!/usr/bin/env python3
"""How far a run's body fits are from the true poses of a synthetic subject written with `--pose-noise`.

Usage: pose_error.py <subject folder> <run folder> [--by-bone]

Reads `<run>/refined_poses.json` (the training frames' given and refined fits, written after stage 1 when
`model.pose_refinement.enabled`) and `<subject>/true_params/<i>.npy`, and prints, for the given and the
refined fits, the mean geodesic angle between fitted and true joint rotations (degrees; every joint but the
root, whose rotation the datasets keep in Rh, plus Rh itself), and the mean distance between the vertices the
two poses place (centimetres; linear blend skinning of `lbs/tvertices.npy` with `lbs/weights.npy`, then
x = R(Rh) x + Th, as the datasets do), split into the part common to all frames (each vertex's mean
displacement over the frames: a shift the canonical body takes on, which the training images cannot reveal)
and the per-frame rest (what the images can correct). `--by-bone` adds, per joint, the per-frame vertex error
of the vertices whose largest weight is that joint's and the joint's own angle error, given and refined: where
the rest of the error sits (a joint whose vertices cover few pixels, such as a hand's or a foot's end, draws
few rays and keeps its given rotation), and the cosine between the corrections made and those the truth
needed (near 0: the images moved the joint, if at all, in no relation to its error). numpy only.
"""
import json
import os
import sys

import numpy as np


def rodrigues(v):
    v = np.asarray(v, dtype=np.float64)
    theta = np.linalg.norm(v)
    if theta < 1e-12:
        return np.eye(3)
    k = v / theta
    kx = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + np.sin(theta) * kx + (1 - np.cos(theta)) * kx @ kx


def angle_between(a, b):
    """Geodesic angle (radians) between two rotation matrices."""
    cos = (np.trace(a.T @ b) - 1) / 2
    return float(np.arccos(np.clip(cos, -1.0, 1.0)))


def posed_vertices(lbs, joints_aa, rh, th):
    joints, parents, vertices, weights = lbs
    k = len(joints)
    rot = [rodrigues(joints_aa[j]) for j in range(k)]
    g = [None] * k
    for j in range(k):
        local = np.eye(4)
        local[:3, :3] = rot[j]
        local[:3, 3] = joints[j] - (joints[parents[j]] if parents[j] >= 0 else 0)
        g[j] = local if parents[j] < 0 else g[parents[j]] @ local
    bones = np.stack([gj @ np.block([[np.eye(3), -joints[j][:, None]], [np.zeros((1, 3)), 1]])
                      for j, gj in enumerate(g)])
    blended = np.einsum("vk,kij->vij", weights, bones)
    homogeneous = np.concatenate([vertices, np.ones((len(vertices), 1))], axis=1)
    local = np.einsum("vij,vj->vi", blended, homogeneous)[:, :3]
    return local @ rodrigues(rh).T + th


def load_lbs(subject):
    """The subject's body model: joints `[K, 3]`, parents `[K]` (-1 at the root; stored as unsigned -1 or
    2^32 - 1 by some writers), template vertices `[V, 3]` and skinning weights `[V, K]`, metres."""
    lbs_dir = os.path.join(subject, "lbs")
    parents = np.load(os.path.join(lbs_dir, "parents.npy")).astype(np.int64)
    parents = np.where((parents < 0) | (parents >= 2**31), -1, parents)
    return (np.load(os.path.join(lbs_dir, "joints.npy")).astype(np.float64), parents,
            np.load(os.path.join(lbs_dir, "tvertices.npy")).astype(np.float64),
            np.load(os.path.join(lbs_dir, "weights.npy")).astype(np.float64))


def pose_of(entry):
    return (np.array(entry["joint_rotations"], dtype=np.float64),
            np.array(entry["global"]["rh"], dtype=np.float64),
            np.array(entry["global"]["th"], dtype=np.float64))


def true_pose(subject, frame):
    params = np.load(os.path.join(subject, "true_params", f"{frame}.npy"), allow_pickle=True).item()
    return (np.asarray(params["poses"], dtype=np.float64).reshape(-1, 3),
            np.asarray(params["Rh"], dtype=np.float64).reshape(3),
            np.asarray(params["Th"], dtype=np.float64).reshape(3))


def errors(lbs, fit, truth):
    """Each joint's angle error (radians, `[K]`), Rh's, and the vertices' displacements from the truth
    (metres, `[V, 3]`)."""
    (fj, frh, fth), (tj, trh, tth) = fit, truth
    joints = [angle_between(rodrigues(a), rodrigues(b)) for a, b in zip(fj, tj)]
    rh = angle_between(rodrigues(frh), rodrigues(trh))
    displacement = posed_vertices(lbs, fj, frh, fth) - posed_vertices(lbs, tj, trh, tth)
    return joints, rh, displacement


def main():
    args = sys.argv[1:]
    by_bone = args[2:] == ["--by-bone"]
    if len(args) != 2 and not by_bone:
        sys.exit(__doc__)
    subject, run = args[:2]
    lbs = load_lbs(subject)
    with open(os.path.join(run, "refined_poses.json")) as f:
        frames = json.load(f)
    truths = [true_pose(subject, entry["frame"]) for entry in frames]
    rows = {"given": [], "refined": []}
    for entry, truth in zip(frames, truths):
        for kind in rows:
            rows[kind].append(errors(lbs, pose_of(entry[kind]), truth))
    per_bone = {}
    for kind, values in rows.items():
        joints = np.array([j for j, _, _ in values])  # [F, K] radians
        # Every joint but the root, whose rotation the datasets keep in Rh, plus Rh itself.
        angles = np.concatenate([joints[:, 1:], np.array([[rh] for _, rh, _ in values])], axis=1)
        d = np.stack([d for _, _, d in values])  # [F, V, 3]
        common = d.mean(axis=0)
        cm = lambda x: 100 * float(np.mean(np.linalg.norm(x, axis=-1)))
        print(f"{kind}: mean joint angle error {np.degrees(angles.mean()):.3f} deg, mean vertex error {cm(d):.3f} cm"
              f" over {len(values)} training frames (common to all frames {cm(common):.3f} cm,"
              f" per frame {cm(d - common):.3f} cm)")
        # Per vertex, its mean per-frame error (cm); per joint, its mean angle error (degrees).
        per_bone[kind] = (100 * np.linalg.norm(d - common, axis=-1).mean(axis=0), np.degrees(joints.mean(axis=0)))
    if by_bone:
        made = np.stack([pose_of(e["refined"])[0] - pose_of(e["given"])[0] for e in frames])
        needed = np.stack([t[0] - pose_of(e["given"])[0] for e, t in zip(frames, truths)])
        print_by_bone(lbs[3].argmax(axis=1), per_bone, agreement(made, needed))


def agreement(made, needed):
    """Per joint, the cosine between the corrections refinement made and those the truth needed, over all
    frames and axes (`[F, K, 3]` axis-angle differences from the given fit: a first-order measure, fine at
    a few degrees): 1 where every correction points at the truth, about 0 where they are unrelated to it."""
    dot = (made * needed).sum(axis=(0, 2))
    norms = np.sqrt((made**2).sum(axis=(0, 2)) * (needed**2).sum(axis=(0, 2)))
    return np.divide(dot, norms, out=np.zeros_like(dot), where=norms > 0)


def print_by_bone(owner, per_bone, agree):
    """Per joint: the mean per-frame error (cm) of the vertices whose largest weight is its, its own angle
    error (degrees), given and refined, and how well its corrections point at the truth (`agreement`)."""
    (given_cm, given_deg), (refined_cm, refined_deg) = per_bone["given"], per_bone["refined"]
    print("joint  vertices  per-frame cm given  refined  angle deg given  refined  agreement")
    for j in range(len(given_deg)):
        mine = owner == j
        if not mine.any():
            continue
        print(f"{j:5d} {mine.sum():9d} {given_cm[mine].mean():18.2f} {refined_cm[mine].mean():8.2f}"
              f" {given_deg[j]:16.2f} {refined_deg[j]:8.2f} {agree[j]:10.2f}")

if __name__ == "__main__":
    main()
