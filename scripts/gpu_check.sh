#!/usr/bin/env bash
# Issue 17's GPU checks as one command, for a lent device machine: the CUDA tests (skipped
# without a GPU), the XLFM RL iteration at 2048^2 x 64 depths on the GPU (goal <= 20 ms on an
# H100) and the conventional build on the GPU. Never part of CI; the suite passes without a GPU.
#
# The device machine's python3 has torch (CUDA), numpy, scipy, tifffile, pytest, tqdm and
# safetensors but not pydantic, and cannot download. Fetch the missing wheels here once:
#
#   echo /.whl/ >> .git/info/exclude
#   python3 -m pip download --no-deps --only-binary=:all: --python-version 3.12 --implementation cp \
#       --platform manylinux_2_17_x86_64 --platform manylinux2014_x86_64 -d .whl \
#       pydantic==2.12.5 pydantic-core==2.41.5 annotated-types==0.8.0 typing-inspection==0.4.5
#
# then run it there with the device tool: command "bash scripts/gpu_check.sh", carry [".whl"],
# timeout_s 540. Here (no GPU) `PYTHON=.venv/bin/python bash scripts/gpu_check.sh` runs the same
# steps and reports that CUDA is absent. Output: the terminal and $OUT (default gpu_check_out/).
set -uo pipefail
python="${PYTHON:-python3}"
out="${OUT:-gpu_check_out}"
mkdir -p "$out"
export PYTHONUNBUFFERED=1 PYTHONPATH="$PWD"
if ! "$python" -c "import pydantic" 2> /dev/null && compgen -G ".whl/*.whl" > /dev/null; then
    "$python" -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade \
        --target /tmp/lfm_site .whl/*.whl || exit 1
    export PYTHONPATH="/tmp/lfm_site:$PWD"
fi
# Without an install (the device machine has none), lfm_studio.resources is the top-level resources/
# folder, which pyproject maps into the package: link it where the import looks for it.
[ -e lfm_studio/resources ] || ln -s ../resources lfm_studio/resources
(nvidia-smi 2>&1 || echo "nvidia-smi: not here") > "$out/nvidia_smi.txt"
"$python" -c "import torch; print('torch', torch.__version__, '| CUDA:', torch.cuda.get_device_name() if torch.cuda.is_available() else 'not available')" \
    2>&1 | tee "$out/torch.txt"

echo "## 1. CUDA tests (every test file with a CUDA case; -rs lists what was skipped and why)"
mapfile -t files < <(grep -rl "cuda.is_available()" tests/engine | sort)
timeout 200 "$python" -m pytest -q -rs -p no:cacheprovider -p no:randomly -o addopts="" "${files[@]}" 2>&1 \
    | tee "$out/cuda_tests.txt" | tail -25

echo "## 2. XLFM RL iteration, 2048^2 camera x 64 depths, on the GPU"
timeout 180 "$python" benchmarks/reconstruct.py --cuda-only --skip-quality --depths 64 2>&1 | tee "$out/xlfm_cuda.txt"

echo "## 3. Conventional build (10x/0.3, 41 x 41 lenslets, 31 depths, standard preset) on the GPU and on 1 and 8 CPU workers"
timeout 120 "$python" benchmarks/conventional_build.py --device cuda --threads 1 --no-reference 2>&1 | tee "$out/conventional_cuda.txt"
timeout 60 "$python" benchmarks/conventional_build.py --threads 1 8 --no-reference 2>&1 | tee "$out/conventional_cpu.txt"
