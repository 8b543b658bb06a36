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
  pydantic pydantic-core typing-inspection annotated-types mediapy
)
python3 -m pip download --no-deps --only-binary=:all: --python-version 3.12 --implementation cp \
  --platform manylinux_2_28_x86_64 --platform manylinux_2_27_x86_64 --platform manylinux_2_17_x86_64 \
  --platform manylinux2014_x86_64 --platform manylinux1_x86_64 --platform manylinux_2_24_x86_64 \
  --platform manylinux_2_31_x86_64 --platform manylinux_2_34_x86_64 \
  -d .whl "${PKGS[@]}"
du -sh .whl
