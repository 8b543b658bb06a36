# Source this on the GPU machine (repo root): installs the carried wheels into /tmp/site, points Python at
# them and at this checkout, registers the physgs methods with nerfstudio and builds gsplat's CUDA code
# (or reuses a build carried in .gsplat_build/).
set -e
python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade --target /tmp/site .whl/*.whl
export PYTHONPATH=/tmp/site:$PWD PATH=/tmp/site/bin:$PATH
export TORCH_CUDA_ARCH_LIST=9.0 MAX_JOBS=16 PYTHONUNBUFFERED=1
export TORCH_EXTENSIONS_DIR=$PWD/.gsplat_build
# A carried build is reused only if ninja sees its objects as newer than the freshly unpacked sources.
if [ -f .gsplat_build/gsplat_cuda/gsplat_cuda.so ]; then
  find /tmp/site/gsplat/cuda/csrc -type f -exec touch -d "2001-01-01" {} +
fi
export NERFSTUDIO_METHOD_CONFIGS="physgs=method_configs.physgs_config:physgs_method,physgs-lite=method_configs.physgs_config:physgs_lite_method"
set +e
