#!/usr/bin/env python3
"""The step of `anerf bench` in PyTorch: the same networks, the same batch, the same loss and optimiser.

One step is the model's per-point work at training time with every point surviving culling (see
crates/anerf-run/src/bench/step.rs): frame blend weights (MLP 1), inverse skinning, the canonical NeRF (MLP 2),
canonical blend weights at the warped points (MLP 3), stage 1's objective with each point a ray of its own (colour
MSE + smooth-L1 consistency; the presets weigh no residual penalty), backward, gradient clipping to ±40 and an
Adam step.

The network sizes come from the Rust presets, so both sides always agree:

    cargo run -- bench --describe --presets paper > /tmp/paper.json
    scripts/bench/.venv/bin/python scripts/bench/torch_reference.py --config /tmp/paper.json --steps 3

Prints one JSON object (the same keys as `anerf bench --json`). Run it in scripts/bench/.venv
(scripts/bench/setup_torch.sh), never in CI.
"""

import argparse
import json
import math
import os
import resource
import time

import torch
from torch import nn
from torch.nn import functional as F

JOINTS = 24
FRAMES = 8


def encode(x: torch.Tensor, frequencies: int) -> torch.Tensor:
    """[x, sin(2^0 x), cos(2^0 x), ...]: the reference embedder (no π)."""
    parts = [x]
    for l in range(frequencies):
        s = x * float(1 << l)
        parts += [torch.sin(s), torch.cos(s)]
    return torch.cat(parts, 1)


def uniform_linear(d_in, d_out, fan_in, bias=True):
    layer = nn.Linear(d_in, d_out, bias=bias)
    bound = 1.0 / fan_in**0.5
    nn.init.uniform_(layer.weight, -bound, bound)
    if bias:
        nn.init.uniform_(layer.bias, -bound, bound)
    return layer


class HashGrid(nn.Module):
    """anerf_core::kernels::hash_grid::reference::encode: every corner of every level gathered with one
    index_select (PyTorch has no hash-grid kernel on the CPU)."""

    PRIMES = (1, 2654435761, 805459861)

    def __init__(self, c):
        super().__init__()
        levels, self.t, self.f, self.h = c["levels"], 1 << c["log2_table_size"], c["features_per_level"], c["half_extent"]
        growth = (math.log(c["finest_resolution"]) - math.log(c["base_resolution"])) / (levels - 1) if levels > 1 else 0.0
        self.res = [round(c["base_resolution"] * math.exp(growth * i)) for i in range(levels)]
        self.table = nn.Parameter(torch.empty(levels * self.t, self.f).uniform_(-1e-4, 1e-4))

    def output_dim(self):
        return len(self.res) * self.f

    def forward(self, x):
        n = x.shape[0]
        u = ((x + self.h) / (2 * self.h)).clamp(0.0, 1.0)
        rows, weights = [], []
        for level, res in enumerate(self.res):
            p = u * res
            base = p.detach().floor().clamp(0, res - 1)
            frac = p - base
            b = base.long()
            side = res + 1
            for c in range(8):
                v = [b[:, a] + ((c >> a) & 1) for a in range(3)]
                if side**3 <= self.t:
                    row = v[0] + (v[1] + v[2] * side) * side
                else:
                    row = (v[0] ^ (v[1] * self.PRIMES[1]) ^ (v[2] * self.PRIMES[2])) & (self.t - 1)
                rows.append(row + level * self.t)
                w = None
                for a in range(3):
                    wa = frac[:, a] if (c >> a) & 1 else 1.0 - frac[:, a]
                    w = wa if w is None else w * wa
                weights.append(w)
        levels = len(self.res)
        g = self.table.index_select(0, torch.cat(rows)).reshape(levels, 8, n, self.f)
        w = torch.stack(weights).reshape(levels, 8, n, 1)
        return (g * w).sum(1).permute(1, 0, 2).reshape(n, levels * self.f)


class PointInput(nn.Module):
    """A field's hash grid when the config has one, else the positional encoding."""

    def __init__(self, cfg, which):
        super().__init__()
        enc = cfg.get("encoding", {"kind": "frequency"})
        self.grid = HashGrid(enc[which]) if enc["kind"] == "hash_grid" else None
        self.frequencies = cfg["xyz_frequencies"]

    def output_dim(self):
        return self.grid.output_dim() if self.grid is not None else 3 + 6 * self.frequencies

    def forward(self, x):
        return self.grid(x) if self.grid is not None else encode(x, self.frequencies)


class SkipMlp(nn.Module):
    """anerf_core::model::mlp::SkipMlp: the conditioning enters the first and the skip layer through its own
    bias-free projection, computed once per batch."""

    def __init__(self, d_in, cond, width, depth, skip):
        super().__init__()
        self.skip = skip
        full = d_in + cond
        layers, projections = [], []
        for i in range(depth):
            joins = i == 0 or (skip is not None and i == skip + 1)
            if i == 0:
                d, fan = d_in, full
            elif joins:
                d, fan = width + d_in, width + full
            else:
                d, fan = width, width
            layers.append(uniform_linear(d, width, fan))
            if joins and cond > 0:
                projections.append(uniform_linear(cond, width, fan, bias=False))
        self.layers = nn.ModuleList(layers)
        self.projections = nn.ModuleList(projections)

    def forward(self, x, c=None):
        projected = [p(c) for p in self.projections] if c is not None else []
        h = x
        for i, layer in enumerate(self.layers):
            joins = i == 0 or (self.skip is not None and i == self.skip + 1)
            z = layer(h)
            if joins and projected:
                z = z + projected.pop(0)
            h = F.relu(z)
            if self.skip == i:
                h = torch.cat([h, x], 1)
        return h


class CanonicalNerf(nn.Module):
    def __init__(self, cfg):
        super().__init__()
        w = cfg["width"]
        self.points = PointInput(cfg, "nerf")
        self.dir_frequencies = cfg["dir_frequencies"]
        d = 3 + 6 * cfg["dir_frequencies"]
        self.trunk = SkipMlp(self.points.output_dim(), 0, w, cfg["depth"], cfg.get("skip"))
        self.density = uniform_linear(w, 1, w)
        self.feature = uniform_linear(w, w, w)
        self.appearance_fc = uniform_linear(w + cfg["appearance_code_dim"], w, w + cfg["appearance_code_dim"])
        self.view_fc = uniform_linear(w + d, w // 2, w + d)
        self.rgb = uniform_linear(w // 2, 3, w // 2)
        self.appearance = nn.Embedding(FRAMES, cfg["appearance_code_dim"])

    def forward(self, points, dirs, index):
        n = points.shape[0]
        dirs = encode(dirs, self.dir_frequencies)
        h = self.trunk(self.points(points))
        density = self.density(h)
        code = self.appearance.weight[index : index + 1].expand(n, -1)
        f = self.appearance_fc(torch.cat([self.feature(h), code], 1))
        v = F.relu(self.view_fc(torch.cat([f, dirs], 1)))
        return density, torch.sigmoid(self.rgb(v))


class BlendField(nn.Module):
    def __init__(self, cfg):
        super().__init__()
        self.points = PointInput(cfg, "blend")
        self.trunk = SkipMlp(self.points.output_dim(), cfg["blend_code_dim"], cfg["width"], cfg["depth"], cfg.get("skip"))
        self.head = uniform_linear(cfg["width"], JOINTS, cfg["width"])
        self.codes = nn.Embedding(FRAMES + 1, cfg["blend_code_dim"])

    def forward(self, points, code, prior):
        psi = self.codes.weight[code : code + 1]
        residual = self.head(self.trunk(self.points(points), psi))
        return torch.softmax(torch.log(prior + 1e-9) + residual, 1)


def inverse_lbs(bones, x, w):
    """anerf_core::geometry::skinning::BoneMatrices::inverse (with the same determinant guard)."""
    m = w @ bones
    r0, r1, r2 = m[:, 0:3], m[:, 4:7], m[:, 8:11]
    t = torch.stack([m[:, 3], m[:, 7], m[:, 11]], 1)
    d = x - t
    c0 = torch.cross(r1, r2, dim=1)
    c1 = torch.cross(r2, r0, dim=1)
    c2 = torch.cross(r0, r1, dim=1)
    det = (r0 * c0).sum(1, keepdim=True)
    det = det.masked_fill(det.abs() < 1e-6, 1e-6)
    return (c0 * d[:, 0:1] + c1 * d[:, 1:2] + c2 * d[:, 2:3]) / det


def volume_weights(table, dims, lo, size, points):
    """Trilinear lookup with one gather for all 8 corners (anerf_core::geometry::VolumeTensor::sample)."""
    n = points.shape[0]
    base, frac = [], []
    for a in range(3):
        cells = float(dims[a] - 1)
        u = ((points[:, a : a + 1] - lo) * (cells / size)).clamp(0.0, cells)
        i0 = u.detach().floor().clamp(0.0, max(dims[a] - 2.0, 0.0))
        frac.append(u - i0)
        base.append(i0)
    indices, weights = [], []
    for c in range(8):
        idx, w = [], None
        for a in range(3):
            hi = (c >> a) & 1 == 1
            idx.append((base[a] + 1.0).clamp(max=dims[a] - 1.0) if hi else base[a])
            wa = frac[a] if hi else 1.0 - frac[a]
            w = wa if w is None else w * wa
        indices.append(((idx[0] * dims[1] + idx[1]) * dims[2] + idx[2]).reshape(n))
        weights.append(w)
    gathered = table.index_select(0, torch.cat(indices).long()).reshape(8, n, JOINTS + 1)
    values = (gathered * torch.stack(weights, 0)).sum(0)
    return values[:, :JOINTS]


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--config", required=True, help="JSON written by `bench --describe` (one preset)")
    parser.add_argument("--points", type=int, default=65536)
    parser.add_argument("--steps", type=int, default=3, help="timed steps after one warm-up step")
    parser.add_argument("--threads", type=int, default=0, help="torch threads (0: PyTorch's default)")
    parser.add_argument("--device", default="cpu", help="torch device: cpu, cuda, cuda:1, ...")
    args = parser.parse_args()
    dev = torch.device(args.device)
    if dev.type == "cuda" and not torch.cuda.is_available():
        parser.error(f"--device {args.device}: this PyTorch sees no CUDA device")
    with open(args.config) as f:
        described = json.loads(f.readline())
    preset, cfg = described["preset"], described["model"]
    if args.threads > 0:
        torch.set_num_threads(args.threads)
    load_before = os.getloadavg()[0]
    torch.manual_seed(7)
    n = args.points
    points = torch.rand(n, 3) - 0.5
    prior = torch.rand(n, JOINTS)
    prior = prior / prior.sum(1, keepdim=True)
    dirs = F.normalize(torch.rand(n, 3) * 2 - 1, dim=1)
    target = torch.rand(n, 3)
    bones = torch.eye(4)[:3].reshape(1, 12).repeat(JOINTS, 1) + 0.05 * torch.randn(JOINTS, 12)
    dims = (32, 32, 32)
    table = torch.rand(32 * 32 * 32, JOINTS + 1)
    table[:, :JOINTS] /= table[:, :JOINTS].sum(1, keepdim=True)
    # Drawn on the CPU (the same numbers on every device), then moved.
    points, prior, dirs, target, bones, table = (t.to(dev) for t in (points, prior, dirs, target, bones, table))
    rows = torch.arange(n, device=dev).reshape(n, 1)
    box = 0.8

    nerf, blend = CanonicalNerf(cfg).to(dev), BlendField(cfg).to(dev)
    params = list(nerf.parameters()) + list(blend.parameters())
    optim = torch.optim.Adam(params, lr=5e-4, eps=1e-8)

    def step():
        w = blend(points, 2, prior)
        canonical = inverse_lbs(bones, points, w)
        inside = ((canonical >= -box) & (canonical <= box)).all(1, keepdim=True)
        density, rgb = nerf(canonical, dirs, 1)
        density = density.masked_fill(~inside, 0.0)
        w_can = blend(canonical, 0, volume_weights(table, dims, -1.0, 2.0, canonical))
        d = density.detach()
        mask = ((d > 0) | (rows == d.argmax())).float()
        diff = (w - w_can).abs()
        inner = diff.clamp(max=1.0)
        per = 0.5 * inner**2 + (diff - inner)
        consistency = (per * mask).sum() / (mask.sum().clamp(min=1.0) * JOINTS)
        loss = F.mse_loss(rgb, target) + consistency
        optim.zero_grad(set_to_none=True)
        loss.backward()
        torch.nn.utils.clip_grad_value_(params, 40.0)
        optim.step()
        return loss.item()

    times, cpu = [], []
    for i in range(args.steps + 1):
        started, cpu_started = time.perf_counter(), time.process_time()
        step()
        if i > 0:
            times.append(time.perf_counter() - started)
            cpu.append(time.process_time() - cpu_started)
    ordered = sorted(times)
    k = len(ordered)
    median = None if k == 0 else (ordered[k // 2] if k % 2 else 0.5 * (ordered[k // 2 - 1] + ordered[k // 2]))
    print(
        json.dumps(
            {
                "preset": preset,
                "points": n,
                "step_seconds": times,
                "step_median": median,
                "step_cpu_seconds": cpu,
                "points_per_second": None if median is None else n / median,
                "step_peak_mib": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0,
                "load_before": load_before,
                "torch": torch.__version__,
                "threads": torch.get_num_threads(),
                "device": str(dev),
                "gpu": torch.cuda.get_device_name(dev) if dev.type == "cuda" else None,
                "gpu_peak_mib": torch.cuda.max_memory_allocated(dev) / 2**20 if dev.type == "cuda" else None,
            }
        )
    )


if __name__ == "__main__":
    main()
