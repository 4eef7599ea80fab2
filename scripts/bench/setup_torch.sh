#!/usr/bin/env bash
# Creates scripts/bench/.venv with PyTorch (CPU use only) for torch_reference.py. Never run in CI: PyPI's
# `torch` wheel pulls about 2.8 GB of CUDA packages; the CPU-only index is tried first.
set -euo pipefail
cd "$(dirname "$0")"
python3 -m venv .venv
.venv/bin/python -m pip install --quiet --upgrade pip
if ! .venv/bin/python -m pip install --quiet torch numpy --index-url https://download.pytorch.org/whl/cpu \
    --extra-index-url https://pypi.org/simple 2>/dev/null; then
    echo "the CPU-only index is not reachable; installing PyPI's torch wheel (about 2.8 GB with CUDA packages)"
    .venv/bin/python -m pip install --quiet torch numpy
fi
.venv/bin/python -c "import torch; print('torch', torch.__version__, 'threads', torch.get_num_threads())"
