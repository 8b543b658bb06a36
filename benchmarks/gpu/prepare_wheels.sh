#!/usr/bin/env bash
# Download the wheels the GPU machine's image lacks (it has Python 3.12, torch 2.11+cu130, numpy 2.x, no
# nerfstudio and no internet). Run here, in the repository root; the wheels land in .whl/ (git-ignored),
# which the GPU run carries and installs with --no-deps into /tmp/site.
set -euo pipefail
cd "$(dirname "$0")/../.."
mkdir -p .whl
PKGS=(
  nerfstudio==1.1.5 gsplat==1.4.0 nerfacc==0.5.2 tyro==1.0.17 typeguard docstring-parser
  viser==0.2.7 msgspec websockets yourdfpy trimesh nodeenv plyfile
  splines pytorch-msssim tensorly rawpy pyquaternion fpsample
  pathos multiprocess ppft dill pox defusedxml appdirs pysocks
  pydantic pydantic-core typing-inspection annotated-types mediapy rtree
)
python3 -m pip download --no-deps --only-binary=:all: --python-version 3.12 --implementation cp \
  --platform manylinux_2_28_x86_64 --platform manylinux_2_27_x86_64 --platform manylinux_2_17_x86_64 \
  --platform manylinux2014_x86_64 --platform manylinux1_x86_64 --platform manylinux_2_24_x86_64 \
  --platform manylinux_2_31_x86_64 --platform manylinux_2_34_x86_64 \
  -d .whl "${PKGS[@]}"
du -sh .whl

# `prepare_wheels.sh pathtrace`: also the Mitsuba 3 wheels for the GPU machine's CPUs (the suite's path-traced
# scenes) in .whlpt/, carried on their own call (`PHASE=scenes run_gpu.sh grid`): a call carries at most 64 MiB,
# so the wheel keeps only the scalar_rgb variant the suite renders with and drops plugins it never loads.
if [ "${1:-}" = pathtrace ]; then
  V=$(python3 -c "import mitsuba; print(mitsuba.__version__)") DV=$(python3 -c "import drjit; print(drjit.__version__)")
  T=$(mktemp -d) R=$PWD; mkdir -p .whlpt; rm -f .whlpt/*.whl
  python3 -m pip download --no-deps --only-binary=:all: --python-version 3.12 --implementation cp \
    --platform manylinux_2_28_x86_64 --platform manylinux_2_17_x86_64 -d "$T" "mitsuba==$V" "drjit==$DV"
  mv "$T"/drjit-*.whl .whlpt/
  (cd "$T" && mkdir x && cd x && unzip -q ../mitsuba-*.whl \
    && rm -f mitsuba/cuda_ad_* mitsuba/llvm_ad_* mitsuba/scalar_spectral* && rm -rf mitsuba/data/sunsky \
    && for p in ellipsoids ellipsoidsmesh volpath volpathmis sdfgrid sunsky timed_sunsky bsplinecurve linearcurve \
         ptracer prbvolpath; do rm -f mitsuba/plugins/$p.so; done \
    && python3 -c "import glob, os; r = glob.glob('*.dist-info/RECORD')[0]; ls = [l for l in open(r) if os.path.exists(l.split(',')[0])]; open(r, 'w').writelines(ls)" \
    && zip -q -r -9 "$R/.whlpt/$(basename ../mitsuba-*.whl)" .)
  cp .whl/rtree-*.whl .whl/trimesh-*.whl .whlpt/  # the figurine family's meshes (trimesh) in the scenes phase
  rm -rf "$T"; du -sh .whlpt
fi
