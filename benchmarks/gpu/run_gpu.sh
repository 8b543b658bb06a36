#!/usr/bin/env bash
# One GPU session's measurements, in two parts that each fit a 10-minute command (see benchmarks/README.md).
#   bash benchmarks/gpu/run_gpu.sh kernels   # rasterizer parity, lifting, mass integration, GPU tests
#   [ROUNDS=3] bash benchmarks/gpu/run_gpu.sh training  # physgs vs splatfacto-big (ROUNDS pairs, A B A B ...)
#   BASE=../other_checkout bash benchmarks/gpu/run_gpu.sh perf  # issue 13: exports before/after
#   bash benchmarks/gpu/run_gpu.sh perf-training                  # issue 13: training cost on the same scene
#   SEEDS="404 505" bash benchmarks/gpu/run_gpu.sh suite          # issue 12: CPU mass suite + gsplat build
#   bash benchmarks/gpu/run_gpu.sh mem       # issue 13: memory and iteration cost of the material heads (chair)
#   HEAD=lifted bash benchmarks/gpu/run_gpu.sh full   # the full run with another material head
#   BASE=.export_base bash benchmarks/gpu/run_gpu.sh export  # issues 12+13: full chair run, its mass, exports before/after
#                                            # (MID=NAME=DIR: a third tree between them)
#   OBJECTS=5 STEPS=3000 bash benchmarks/gpu/run_gpu.sh batch     # issue 14: physgs batch (local) over the suite
#   PHASE=scenes CPU_SEEDS="1313 1414" bash benchmarks/gpu/run_gpu.sh msuite  # issue 12: GPU suite scenes (+ CPU suite)
#   PHASE=train OBJECTS="mug chair" bash benchmarks/gpu/run_gpu.sh msuite     # ... then train and score them
#   PHASE=scenes SEEDS="70001 70002 70003" bash benchmarks/gpu/run_gpu.sh grid  # the mass suite's grid: scenes (.whlpt)
#   PHASE=runs SEEDS="70001 70002 70003" bash benchmarks/gpu/run_gpu.sh grid    # ... then its runs, detached (.whl)
#                                            # (EXPORT_ARGS="--mass.X Y" ALT=NAME: then every run re-exported so too,
#                                            # scored as mass_suite_NAME.json beside the baseline)
#                                            # (RENDERERS="mitsuba project", FAMILIES: all; carry .meshes/, a copy of
#                                            # ../shared/data's bunny.obj and armadillo.obj, for the figurine family)
#   [BASE=DIR] bash benchmarks/gpu/run_gpu.sh after  # issue 13, after `export` on the same machine: mass_integration.py
#                                            # (and BASE's beside it),
#                                            # the run's ns-eval, physgs vs splatfacto-big
# Results go to $OUT (or ./gpu_results). Needs .whl/ (benchmarks/gpu/prepare_wheels.sh) on a machine
# without nerfstudio; optional .gsplat_build/ (a carried gsplat JIT build).
set -uo pipefail
cd "$(dirname "$0")/../.."
OUT=${OUT:-$PWD/gpu_results}; mkdir -p "$OUT"
T0=$(date +%s)
elapsed() { echo $(( $(date +%s) - T0 )); }
OBJECT=${OBJECT:-stool} VIEWS=${VIEWS:-40} RES=${RES:-384}
PERF_SCENE=/tmp/physgs_${OBJECT}_${VIEWS}x${RES}
perf_scene() {  # the issue's second scene: a generated stool, 40 views at 384 px, simulated perception
  [ -f "$PERF_SCENE/materials.json" ] && return
  python3 -m physgs_nerfstudio.cli synth --out "$PERF_SCENE" --object "$OBJECT" --views "$VIEWS" \
    --resolution "$RES" --overwrite 2>&1 | tail -1
  python3 -m physgs_nerfstudio.cli perceive --data "$PERF_SCENE" --no-progress --max-concurrency 16 vlm:simulated \
    2>&1 | tail -1
}
MESHES() { [ -f .meshes/bunny.obj ] && echo "--mesh-dir .meshes"; }  # the figurine's meshes (in the copy the job runs in)
if [ "${1:-}" = grid ] && [ "${PHASE:-runs}" = scenes ]; then
  # the mass suite's grid, step 1 (carry .whlpt/, the Mitsuba wheels: prepare_wheels.sh pathtrace): every scene of
  # SEEDS, both renderers, rendered on the machine's CPUs, detached; step 2 is `PHASE=runs ... grid` (carry .whl/)
  python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --target /tmp/msite .whlpt/*.whl || exit 1
  mkdir -p /tmp/suite; cp -a . /tmp/suite_repo
  (cd /tmp/suite_repo && PYTHONPATH=/tmp/msite:/tmp/suite_repo OMP_NUM_THREADS=1 setsid nohup python3 \
    benchmarks/mass_suite.py --scenes-only --seeds ${SEEDS:?SEEDS=...} --renderers ${RENDERERS:-mitsuba project} \
    ${FAMILIES:+--families $FAMILIES} $(MESHES) --jobs 16 \
    --out /tmp/suite > /tmp/scenes.log 2>&1 < /dev/null &)
  sleep 30; tail -2 /tmp/scenes.log; exit 0
fi
case "${1:-}" in perf|suite|mem|export|batch|msuite|grid) export GSPLAT_BUILD_LATER=1 ;; esac  # compiled beside CPU work
if ! python3 -c "import nerfstudio" 2>/dev/null; then source benchmarks/gpu/setup_env.sh; fi
nvidia-smi --query-gpu=name,memory.total,driver_version --format=csv | tee "$OUT/gpu.txt"
SCENE=/tmp/physgs_gpu_scene
make_scene() {
  [ -f "$SCENE/materials.json" ] && return
  python3 -m physgs_nerfstudio.cli synth --out "$SCENE" --object chair --views 60 --resolution 512 --overwrite
  python3 -m physgs_nerfstudio.cli perceive --data "$SCENE" --vlm simulated --segmenter builtin \
    --no-progress --max-concurrency 16
}
case "${1:-kernels}" in
  kernels)  # (mass: the export benchmark, `perf`, times `physgs export --outputs mass` on a trained scene)
    python3 benchmarks/gpu/bench_kernels.py --out "$OUT/kernels.json" 2>&1 | tee "$OUT/kernels.log"
    python3 -m pytest -q -m gpu tests/ -p no:cacheprovider 2>&1 | tail -15 | tee "$OUT/gpu_tests.txt"
    ;;
  training)
    make_scene 2>&1 | tail -20 | tee "$OUT/scene.log"
    python3 benchmarks/gpu/bench_training.py --data "$SCENE" --steps 1500 --warmup 300 ${METHODS:+--methods $METHODS} \
      --rounds "${ROUNDS:-1}" --out "$OUT/training.json" 2>&1 | grep -v Warning | tee "$OUT/training.log" | tail -20
    ;;
  perf)
    # issue 13 (about 9.5 minutes on an H100): a generated scene, a short `ns-train physgs`, then `physgs export`
    # of this tree vs BASE (another checkout) side by side (bench_export.py); the gsplat build (stamped) is
    # copied to $OUT for `perf-training`, which then needs no compilation even on a fresh machine.
    BASE=${BASE:?BASE=path of the checkout to compare against}
    STEPS=${STEPS:-3000} LIMIT=${LIMIT:-560}
    echo "[$(elapsed) s] scene (gsplat builds beside it: setup_env.sh with GSPLAT_BUILD_LATER=1)"
    perf_scene
    wait  # the gsplat build
    echo "[$(elapsed) s] gsplat: $(cat "$OUT/gsplat_build.txt" 2>/dev/null)"
    python3 -m nerfstudio.scripts.train physgs --data "$PERF_SCENE" --max-num-iterations "$STEPS" --vis tensorboard \
      --steps-per-eval-image 100000000 --steps-per-eval-all-images 100000000 --steps-per-save "$STEPS" \
      --output-dir /tmp/physgs_runs --timestamp perf 2>&1 | grep -v Warning | tail -3
    CFG=$(ls /tmp/physgs_runs/*/physgs/perf/config.yml)
    echo "[$(elapsed) s] exports"
    python3 benchmarks/gpu/bench_export.py --config "$CFG" --tree "before=$BASE" --tree "after=$PWD" --views 10 \
      --breakdown --touch-gsplat --budget-s $((LIMIT - 45 - $(elapsed))) --out "$OUT/export.json" 2>&1 \
      | grep -v Warning > "$OUT/export.log"; tail -45 "$OUT/export.log"
    cp .gsplat_build/gsplat_cuda/gsplat_cuda.so .gsplat_build/gsplat_cuda/physgs_build_stamp.json "$OUT/" 2>/dev/null
    echo "[$(elapsed) s] done"
    ;;
  perf-training)
    # the training cost of physgs vs splatfacto-big on the `perf` scene (run after `perf`; carry the gsplat build
    # it returned in .gsplat_build/gsplat_cuda/ to skip the compilation on a fresh machine)
    perf_scene
    python3 benchmarks/gpu/bench_training.py --data "$PERF_SCENE" --steps ${TRAIN_STEPS:-1000} --warmup 300 \
      --out "$OUT/training.json" 2>&1 | grep -v Warning | tee "$OUT/training.log" | tail -4
    echo "[$(elapsed) s] done"
    ;;
  suite)
    # issue 12: the CPU mass suite (`physgs demo` settings) on this machine's cores with CUDA hidden, while gsplat
    # builds beside it; ALT_ARGS: the same runs re-exported with these export flags as well (ALT_NAME); the stamped
    # build is returned as $OUT/gsplat_cuda.tgz for later calls (tar xzf gsplat_cuda.tgz -C .gsplat_build)
    SEEDS=${SEEDS:-404 505} JOBS=${JOBS:-12}
    CUDA_VISIBLE_DEVICES= python3 benchmarks/mass_suite.py --seeds $SEEDS --jobs "$JOBS" --out /tmp/mass_suite \
      > "$OUT/mass_suite.log" 2>&1; tail -2 "$OUT/mass_suite.log"
    cp /tmp/mass_suite/mass_suite.json "$OUT/" 2>/dev/null
    if [ -n "${ALT_ARGS:-}" ]; then
      echo "[$(elapsed) s] re-export: $ALT_ARGS"
      CUDA_VISIBLE_DEVICES= python3 benchmarks/mass_suite.py --seeds $SEEDS --jobs "$JOBS" --out /tmp/mass_suite \
        --alt-name "${ALT_NAME:-alt}" --export-args="$ALT_ARGS" > "$OUT/mass_suite_${ALT_NAME:-alt}.log" 2>&1
      tail -2 "$OUT/mass_suite_${ALT_NAME:-alt}.log"; cp /tmp/mass_suite/mass_suite_${ALT_NAME:-alt}.json "$OUT/" 2>/dev/null
    fi
    echo "[$(elapsed) s] suite done; waiting for gsplat"; wait
    tar czf "$OUT/gsplat_cuda.tgz" -C .gsplat_build gsplat_cuda/gsplat_cuda.so gsplat_cuda/physgs_build_stamp.json 2>/dev/null
    cat "$OUT/gsplat_build.txt" 2>/dev/null; echo "[$(elapsed) s] done"
    ;;
  mem)
    # issue 13 (about 5-8 minutes on an H100 with a carried gsplat build): each method in its own process on the
    # chair scene; per method iteration time, peak memory per phase, static bytes, liftings, eval material accuracy
    make_scene 2>&1 | tail -3 | tee "$OUT/scene.log"
    wait  # the gsplat build (setup_env.sh with GSPLAT_BUILD_LATER=1), beside the scene
    mkdir -p "$OUT/gsplat_cuda"; cp .gsplat_build/gsplat_cuda/gsplat_cuda.so .gsplat_build/gsplat_cuda/physgs_build_stamp.json \
      "$OUT/gsplat_cuda/" 2>/dev/null
    echo "[$(elapsed) s] scene; gsplat: $(cat "$OUT/gsplat_build.txt" 2>/dev/null)"
    # the fifth: the lifted head with its liftings rendered 8 channels at a time, and lifted every 500 steps
    METHODS=${METHODS:-"splatfacto-big physgs physgs:material_head=latent physgs:material_head=lifted
      physgs:material_head=lifted,lift_channel_chunk=8,lifting_every=500"}
    python3 benchmarks/gpu/bench_training.py --data "$SCENE" --steps ${TRAIN_STEPS:-1500} --warmup 300 \
      --methods $METHODS --out "$OUT/mem.json" 2>&1 | grep -v Warning | tee "$OUT/mem.log" | tail -8
    echo "[$(elapsed) s] done"
    ;;
  export)
    # issues 12 and 13 in one command (about 9 minutes on an H100 with a carried gsplat build): the chair scene
    # (60 views at 512 px), `ns-train physgs` (STEPS, default 7000), the user's `physgs export` (its mass and report
    # copied at once), then `physgs export` of this tree vs BASE side by side with a per-stage breakdown
    # (bench_export.py) until LIMIT seconds; the run's ns-eval last if time is left
    BASE=${BASE:?BASE=path of the checkout to compare against}
    STEPS=${STEPS:-7000} LIMIT=${LIMIT:-560}
    make_scene 2>&1 | tail -3 | tee "$OUT/scene.log"
    wait  # the gsplat build
    echo "[$(elapsed) s] scene; gsplat: $(cat "$OUT/gsplat_build.txt" 2>/dev/null)"
    # the stamped build, returned as one file (carry it back as .gsplat_build/: tar xzf gsplat_cuda.tgz -C .gsplat_build)
    tar czf "$OUT/gsplat_cuda.tgz" -C .gsplat_build gsplat_cuda/gsplat_cuda.so gsplat_cuda/physgs_build_stamp.json 2>/dev/null
    python3 -m nerfstudio.scripts.train physgs --data "$SCENE" --max-num-iterations "$STEPS" --vis tensorboard \
      --steps-per-eval-image 100000000 --steps-per-eval-all-images 100000000 --steps-per-save "$STEPS" \
      --output-dir /tmp/physgs_runs --timestamp gpu 2>&1 | grep -v Warning > /tmp/physgs_full_train.log
    # the last lines, and the geometry that ns-train stored for `physgs export` (its time: the precompute's cost)
    { tail -4 /tmp/physgs_full_train.log; grep -A1 "PhysGS geometry\|geometry was not precomputed" /tmp/physgs_full_train.log; } \
      | tee "$OUT/full_train.log"
    CFG=$(ls /tmp/physgs_runs/*/physgs/gpu/config.yml)
    if [ -z "${SKIP_USER_EXPORT:-}" ]; then  # SKIP_USER_EXPORT=1: only the benchmark below
      echo "[$(elapsed) s] trained; physgs export (all outputs)"
      /usr/bin/time -f "wall %e s, max RSS %M KB" python3 -m physgs_nerfstudio.cli export --load-config "$CFG" \
        --output-dir /tmp/physgs_export > "$OUT/full_export.log" 2>&1; tail -25 "$OUT/full_export.log"
      cp /tmp/physgs_export/report.json "$OUT/full_report.json" 2>/dev/null
    fi
    echo "[$(elapsed) s] exports before/after"  # CASES: the cases, in order; PROFILE=0: no --profile-load/--breakdown
    python3 benchmarks/gpu/bench_export.py --config "$CFG" --tree "before=$BASE" ${MID:+--tree "$MID"} --tree "after=$PWD" \
      --views 10 --warmup \
      --cases ${CASES:-load mass all maps1 mapsN ply} $([ "${PROFILE:-1}" = 1 ] && echo --profile-load --breakdown) \
      --budget-s $((LIMIT - 60 - $(elapsed))) --out "$OUT/export.json" 2>&1 | grep -v Warning > "$OUT/export.log"
    tail -30 "$OUT/export.log"
    if [ $(elapsed) -lt $((LIMIT - 40)) ]; then
      python3 -m nerfstudio.scripts.eval --load-config "$CFG" --output-path "$OUT/full_eval.json" 2>&1 | tail -2
    fi
    echo "[$(elapsed) s] done"
    ;;
  batch)
    # issue 14 (about 6-8 minutes on an H100 at the defaults; the batch is stopped in time in any case):
    # `physgs batch --backend local --method physgs` over generated suite objects on this GPU, all stages, simulated
    # perception; GPU-seconds per scene from the batch's own records (gpu/batch_gpu_seconds.py). The defaults are
    # a REDUCED run, and the script says so: the whole suite at physgs's default 30000 steps is about 12 x 6.5
    # minutes (--dry-run: 375 s a scene), far more than one 10-minute command. OBJECTS: how many of the suite's 12
    # objects (SUITE order: mug chair hammer bottle shoe ...) or their names; STEPS: ns-train iterations (at 500
    # the physgs export of a 24-view 128 px chair failed on a CPU, "carving left no solid voxel"; the 7000-step full
    # run exported; 3000 is what `perf` trains); VIEWS, RES: views and pixels (synth's defaults); LIMIT: seconds
    # this whole command may take (the batch is stopped RESERVE s before it, so that its records come back).
    OBJECTS=${OBJECTS:-5} STEPS=${STEPS:-3000} VIEWS=${VIEWS:-24} RES=${RES:-128} LIMIT=${LIMIT:-540}
    METHOD=${METHOD:-physgs} DEVICE=${DEVICE:-cuda} RESERVE=${RESERVE:-40}
    SUITE_DIR=/tmp/physgs_suite_${VIEWS}x${RES} BOUT=${BOUT:-/tmp/physgs_batch}
    ALL=$(python3 -c "from physgs_nerfstudio.synth.objects import SUITE; print(' '.join(SUITE))")
    case "$OBJECTS" in *[!0-9]*) NAMES=$OBJECTS ;; *) NAMES=$(echo $ALL | cut -d' ' -f1-"$OBJECTS") ;; esac
    DEFAULT_STEPS=$(python3 -c "from physgs_nerfstudio.batch.plan import DEFAULT_ITERATIONS as D; print(D['$METHOD'])")
    RUN="$(echo $NAMES | wc -w) of the 12 suite objects ($NAMES), $VIEWS views at $RES px, $METHOD $STEPS steps on $DEVICE"
    [ "$STEPS" -lt "$DEFAULT_STEPS" ] && RUN="$RUN: a REDUCED run ($METHOD's default is $DEFAULT_STEPS steps)"
    echo "[$(elapsed) s] batch: $RUN" | tee "$OUT/batch_run.txt"
    rm -rf "$BOUT" "$SUITE_DIR"  # a fresh batch: nothing resumed from an earlier call
    # CPU work beside the gsplat build: the scenes (the folder `physgs synth --suite` writes, one dataset per object,
    # written object by object in parallel), and the first import of nerfstudio with the physgs methods (it writes
    # the bytecode of the freshly unpacked wheels, so that the first scene's ns-train does not pay for it)
    (python3 -c "import nerfstudio.scripts.train" >/dev/null 2>&1) &
    SYNTH=()
    for n in $NAMES; do
      python3 -m physgs_nerfstudio.cli synth --object "$n" --out "$SUITE_DIR/$n" --views "$VIEWS" --resolution "$RES" \
        > "$OUT/batch_synth_$n.log" 2>&1 & SYNTH+=($!)
    done
    for pid in "${SYNTH[@]}"; do wait "$pid" || echo "synth of one object failed: see $OUT/batch_synth_*.log"; done
    echo "[$(elapsed) s] $(ls "$SUITE_DIR" | wc -l) scenes in $SUITE_DIR"
    SCENES=$SUITE_DIR
    # the plan's estimate at the method's default steps (what pricing a dataset with --dry-run shows)
    COLUMNS=120 python3 -m physgs_nerfstudio.cli batch --scenes "$SCENES" --output-dir "$BOUT" --method "$METHOD" \
      --dry-run > "$OUT/batch_dry_run.txt" 2>&1; tail -2 "$OUT/batch_dry_run.txt"
    wait  # the gsplat build (setup_env.sh with GSPLAT_BUILD_LATER=1) and the import
    echo "[$(elapsed) s] suite ready; gsplat: $(cat "$OUT/gsplat_build.txt" 2>/dev/null | tr '\n' ' ')"
    mkdir -p "$OUT/gsplat_cuda"; cp .gsplat_build/gsplat_cuda/gsplat_cuda.so .gsplat_build/gsplat_cuda/physgs_build_stamp.json \
      "$OUT/gsplat_cuda/" 2>/dev/null
    copy_batch() {  # the batch's records as they stand (also while it runs: a stopped command keeps them)
      mkdir -p "$OUT/batch/scenes"
      for f in "$BOUT"/scenes/*/state.json; do [ -f "$f" ] && cp "$f" "$OUT/batch/scenes/$(basename "$(dirname "$f")").json"; done
      cp "$BOUT"/batch_summary.json "$BOUT"/batch_scenes.csv "$OUT/batch/" 2>/dev/null
      [ -d "$BOUT/eval" ] && cp -r "$BOUT/eval" "$OUT/batch/"
    }
    (while sleep 20; do copy_batch; done) >/dev/null 2>&1 & COPIER=$!
    BUDGET=$((LIMIT - RESERVE - $(elapsed)))
    echo "[$(elapsed) s] physgs batch (stopped after $BUDGET s if not done)"
    # LPIPS (an eval metric, never a training step) is off: its AlexNet weights cannot be fetched on an offline
    # machine, and each scene's failed fetch would be counted as GPU time
    COLUMNS=160 timeout -k 10 "$BUDGET" python3 -m physgs_nerfstudio.cli batch --scenes "$SCENES" --output-dir "$BOUT" \
      --backend local --method "$METHOD" --stages perceive train export eval --iterations "$STEPS" --device "$DEVICE" \
      --vlm simulated --no-progress --train-args=--pipeline.model.compute-lpips=False > "$OUT/batch.log" 2>&1
    RC=$?
    grep -v -i warn "$OUT/batch.log" | tail -40
    if [ "$RC" = 124 ] || [ "$RC" = 137 ]; then  # stopped: the table, summary and eval of what finished
      echo "[$(elapsed) s] the batch was STOPPED at its budget; summarising the finished stages"
      COLUMNS=160 timeout 30 python3 -m physgs_nerfstudio.cli batch --scenes "$SCENES" --output-dir "$BOUT" \
        --method "$METHOD" --stages eval --device "$DEVICE" --vlm simulated --no-progress > "$OUT/batch_after_stop.log" 2>&1
      grep -v -i warn "$OUT/batch_after_stop.log" | tail -25
    fi
    kill "$COPIER" 2>/dev/null; copy_batch
    mkdir -p "$OUT/batch/train_logs"  # each ns-train log's end (nerfstudio's profiler lines)
    for f in "$BOUT"/scenes/*/train.log; do [ -f "$f" ] && tail -c 4000 "$f" > "$OUT/batch/train_logs/$(basename "$(dirname "$f")").log"; done
    python3 benchmarks/gpu/batch_gpu_seconds.py --output-dir "$BOUT" --method "$METHOD" --out "$OUT/batch_gpu.json" \
      2>&1 | tee "$OUT/batch_gpu.txt"
    # the device returns a handful of files: the records and logs go back as one archive
    (cd "$OUT" && tar czf batch.tgz batch batch_synth_*.log 2>/dev/null && rm -rf batch batch_synth_*.log)
    echo "[$(elapsed) s] done (batch exit code $RC): $RUN"
    if [ -n "${BASE:-}" ] && [ -n "${EXPORT_UNTIL:-}" ]; then  # issue 13 on the first trained scene: exports before/after
      CFG=$(ls "$BOUT"/scenes/*/runs/*/"$METHOD"/*/config.yml 2>/dev/null | head -1)
      [ -n "$CFG" ] && python3 benchmarks/gpu/bench_export.py --config "$CFG" --tree "before=$BASE" --tree "after=$PWD" \
        --views 10 --cases ${CASES:-load ply mass all maps1 mapsN} --warmup --breakdown $([ "${PROFILE:-0}" = 1 ] && echo --profile-load) \
        --budget-s $((EXPORT_UNTIL - $(elapsed))) --out "$OUT/export.json" 2>&1 | grep -v Warning > "$OUT/export.log"
      tail -22 "$OUT/export.log"; echo "[$(elapsed) s] exports done"
    fi
    ;;
  after)
    # issue 13, a second call on the machine that ran `export` (its scene, run and gsplat build are still there):
    # benchmarks/gpu/mass_integration.py at 1M Gaussians, the run's ns-eval (material accuracy on held-out views), and
    # physgs vs splatfacto-big (bench_training.py, each in its own process) on the same scene
    python3 benchmarks/gpu/mass_integration.py --gaussians ${GAUSSIANS:-1000000} --views 54 --size 512 \
      --out "$OUT/mass_integration.json" 2>&1 | tee "$OUT/mass_integration.log" | tail -12
    if [ -n "${BASE:-}" ]; then  # BASE: the same benchmark of that tree, then this tree's again (side by side)
      (cd "$BASE" && python3 benchmarks/gpu/mass_integration.py --gaussians ${GAUSSIANS:-1000000} --views 54 --size 512 \
        --out "$OUT/mass_integration_base.json" 2>&1 | tail -9)
      python3 benchmarks/gpu/mass_integration.py --gaussians ${GAUSSIANS:-1000000} --views 54 --size 512 \
        --out "$OUT/mass_integration_again.json" 2>&1 | tail -9
    fi
    CFG=$(ls /tmp/physgs_runs/*/physgs/gpu/config.yml 2>/dev/null)
    if [ -n "$CFG" ]; then  # the maps cases of bench_export (this tree), then the mass export under cProfile
      python3 benchmarks/gpu/bench_export.py --config "$CFG" --tree "after=$PWD" --views 10 --cases maps1 mapsN \
        --out "$OUT/export_maps.json" 2>&1 | grep -v Warning > "$OUT/export_maps.log"; tail -8 "$OUT/export_maps.log"
      PHYSGS_NO_FAST_EXIT=1 CUDA_LAUNCH_BLOCKING=1 python3 -m cProfile -o /tmp/mass.prof -m physgs_nerfstudio.cli export --load-config "$CFG" \
        --output-dir /tmp/pm --outputs mass --overwrite > /dev/null 2>&1
      python3 -c "import pstats; p = pstats.Stats('/tmp/mass.prof'); p.sort_stats('cumulative').print_stats(120)" \
        > "$OUT/mass_profile.txt" 2>&1
      grep -E "physgs_nerfstudio" "$OUT/mass_profile.txt" | head -45 | cut -c1-150
    fi
    echo "[$(elapsed) s] training cost"
    python3 benchmarks/gpu/bench_training.py --data "$SCENE" --steps ${TRAIN_STEPS:-1500} --warmup 300 \
      --methods ${METHODS:-splatfacto-big physgs} --out "$OUT/training.json" 2>&1 | grep -v Warning | tee "$OUT/training.log" | tail -8
    echo "[$(elapsed) s] done"
    ;;
  grid)
    # the mass suite's grid, step 2 (after PHASE=scenes; carry .whl/): `physgs demo` at its CPU settings but trained on
    # the GPU (--device cuda) for every scene, JOBS at a time, detached in a copy of the checkout (detached.sh); then
    # `bash benchmarks/gpu/detached.sh wait` in back-to-back calls; the rows: /tmp/suite/mass_suite_rows_baseline.jsonl
    wait  # the gsplat build
    bash benchmarks/gpu/detached.sh start "export PYTHONPATH=/tmp/site:/tmp/msite:\$PWD TORCH_EXTENSIONS_DIR=\$PWD/.gsplat_build; while pgrep -f 'mass_suite.py --scenes[-]only' >/dev/null; \
      do sleep 5; done; python3 benchmarks/mass_suite.py --seeds $SEEDS --renderers ${RENDERERS:-mitsuba project} \
      ${FAMILIES:+--families $FAMILIES} $(MESHES) --jobs ${JOBS:-12} \
      --demo-args '--device cuda' --out /tmp/suite > \$OUT/suite.log 2>&1; cp /tmp/suite/mass_suite*.json* \$OUT/" \
      ${EXPORT_ARGS:+"export PYTHONPATH=/tmp/site:/tmp/msite:\$PWD TORCH_EXTENSIONS_DIR=\$PWD/.gsplat_build; python3 benchmarks/mass_suite.py --seeds $SEEDS \
      --renderers ${RENDERERS:-mitsuba project} ${FAMILIES:+--families $FAMILIES} $(MESHES) --jobs ${JOBS:-12} \
      --export-args '$EXPORT_ARGS' --alt-name ${ALT:-alt} --out /tmp/suite > \$OUT/suite_${ALT:-alt}.log 2>&1; \
      cp /tmp/suite/mass_suite*.json* \$OUT/"}
    ;;
  msuite)
    # issue 12, the mass suite at 60 views 512 px on the GPU, in phases that each fit a 10-minute command on one
    # machine kept warm between calls (its /tmp holds the scenes and runs):
    #   PHASE=scenes: the generated OBJECTS (default: all 12) at GSEED (synth + simulated perception, one process per
    #     object on the CPUs); beside them, with CPU_SEEDS, the CPU suite (`physgs demo` settings, CUDA hidden) at
    #     those seeds and its re-export with ALT_ARGS (ALT_NAME)
    #   PHASE=train: `ns-train physgs` (STEPS, 7000) of OBJECTS, CONC at a time on each of the machine's GPUs (round
    #     robin), then `mass_suite.py --trained` (`physgs export --outputs mass` with its defaults, EJOBS = 4 at a
    #     time) -> mass_suite_gpu.json, and with ALT_ARGS the same runs exported with those flags too ->
    #     mass_suite_gpu_ALT_NAME.json (ALT2_ARGS, ALT2_NAME and ALT3_ARGS, ALT3_NAME: more such exports). OBJECTS may
    #     hold indoor_room: it is measured by indoor_room.py --run (-> indoor_room_gpu_sGSEED.json), not the suite.
    #     GPU0=k: the first training goes to GPU k (several invocations side by side).
    #     STABILITY="chair table": then mass_stability.py on those runs (SJOBS = 8 at a time) ->
    #     stability_OBJECT_sGSEED.json
    #   MS=DIR (default /tmp/ms): the folder of the scenes and runs (two variants side by side); SEG_ARGS: perception's
    #     segmenter flags in PHASE=scenes (default "segmenter:builtin", e.g. "segmenter:builtin --segmenter.thin-chroma 4")
    GSEED=${GSEED:-1515} STEPS=${STEPS:-7000} CONC=${CONC:-6} MS=${MS:-/tmp/ms}
    SEG_ARGS=${SEG_ARGS:-segmenter:builtin}
    OBJECTS=${OBJECTS:-"mug chair hammer bottle shoe table pan lamp crate stool dumbbell vase"}
    case "${PHASE:?PHASE=scenes|train}" in
      scenes)
        for o in $OBJECTS; do
          (d=$MS/${o}_s$GSEED; OMP_NUM_THREADS=1 python3 -m physgs_nerfstudio.cli synth --out $d/scene --object $o \
             --seed $GSEED --views 60 --resolution 512 --overwrite > ${MS}_${o}_s$GSEED.log 2>&1 && OMP_NUM_THREADS=1 python3 -m \
             physgs_nerfstudio.cli perceive --data $d/scene --no-progress \
             --max-concurrency 4 vlm:simulated $SEG_ARGS >> ${MS}_${o}_s$GSEED.log 2>&1; echo "[$(elapsed) s] scene $o: $(tail -c 200 ${MS}_${o}_s$GSEED.log | tail -1)") &
        done
        if [ -n "${CPU_SEEDS:-}" ]; then
          CUDA_VISIBLE_DEVICES= python3 benchmarks/mass_suite.py --seeds $CPU_SEEDS --jobs "${JOBS:-8}" --out /tmp/mass_suite \
            > "$OUT/mass_suite.log" 2>&1; tail -1 "$OUT/mass_suite.log"; cp /tmp/mass_suite/mass_suite.json "$OUT/" 2>/dev/null
          if [ -n "${ALT_ARGS:-}" ]; then
            CUDA_VISIBLE_DEVICES= python3 benchmarks/mass_suite.py --seeds $CPU_SEEDS --jobs "${JOBS:-8}" --out /tmp/mass_suite \
              --alt-name "${ALT_NAME:-alt}" --export-args="$ALT_ARGS" > "$OUT/mass_suite_${ALT_NAME:-alt}.log" 2>&1
            tail -1 "$OUT/mass_suite_${ALT_NAME:-alt}.log"; cp /tmp/mass_suite/mass_suite_${ALT_NAME:-alt}.json "$OUT/" 2>/dev/null
          fi
          echo "[$(elapsed) s] CPU suite done"
        fi
        wait; echo "[$(elapsed) s] done"
        ;;
      train)
        # the gsplat build first: trainings started beside it find no gsplat_cuda.so
        [ -n "${GSPLAT_BUILD_PID:-}" ] && wait "$GSPLAT_BUILD_PID"
        echo "[$(elapsed) s] gsplat: $(cat "$OUT/gsplat_build.txt" 2>/dev/null)"
        n=0 NGPU=$(nvidia-smi -L | wc -l)
        for o in $OBJECTS; do
          d=$MS/${o}_s$GSEED
          [ -f $d/scene/materials.json ] || { echo "no scene for $o"; continue; }
          (CUDA_VISIBLE_DEVICES=$(((n + ${GPU0:-0}) % NGPU)) python3 -m nerfstudio.scripts.train physgs --data $d/scene --max-num-iterations "$STEPS" --vis tensorboard \
             --steps-per-eval-image 100000000 --steps-per-eval-all-images 100000000 --steps-per-save "$STEPS" \
             --output-dir $d/runs --timestamp gpu > ${MS}_train_${o}_s$GSEED.log 2>&1; echo "[$(elapsed) s] trained $o: rc $?") &
          n=$((n + 1)); [ $((n % (CONC * NGPU))) -eq 0 ] && wait
        done
        wait
        SUITE=$(for o in $OBJECTS; do [ "$o" = indoor_room ] || echo $o; done)
        if [[ " $OBJECTS " == *" indoor_room "* ]]; then  # beside the suite's exports
          (python3 benchmarks/indoor_room.py --run $MS/indoor_room_s$GSEED --out $MS/room_s$GSEED > $MS/room_s$GSEED.log 2>&1
           cp $MS/room_s$GSEED/indoor_room.json "$OUT/indoor_room_gpu_s$GSEED.json"
           echo "[$(elapsed) s] indoor_room s$GSEED:"; tail -3 $MS/room_s$GSEED.log) &
        fi
        if [ -n "$SUITE" ]; then
          python3 benchmarks/mass_suite.py --trained --objects $SUITE --seeds $GSEED --jobs "${EJOBS:-4}" --out $MS \
            --alt-name gpu > "$OUT/gpu_mass_suite.log" 2>&1
          cut -c1-240 "$OUT/gpu_mass_suite.log" | tail -14; cp $MS/mass_suite_gpu*.json "$OUT/" 2>/dev/null
        fi
        # the same runs exported with ALT_ARGS, ALT2_ARGS and ALT3_ARGS as well (each where set)
        for alt in "${ALT_NAME:-alt}=${ALT_ARGS:-}" "${ALT2_NAME:-alt2}=${ALT2_ARGS:-}" "${ALT3_NAME:-alt3}=${ALT3_ARGS:-}"; do
          name=${alt%%=*} args=${alt#*=}
          [ -n "$args" ] || continue
          python3 benchmarks/mass_suite.py --trained --objects $SUITE --seeds $GSEED --jobs "${EJOBS:-4}" --out $MS \
            --alt-name "gpu_$name" --export-args="$args" > "$OUT/gpu_mass_suite_$name.log" 2>&1
          tail -1 "$OUT/gpu_mass_suite_$name.log"; cp $MS/mass_suite_gpu*.json "$OUT/" 2>/dev/null  # each as it ends
        done
        cp $MS/mass_suite_gpu*.json "$OUT/" 2>/dev/null
        for o in ${STABILITY:-}; do
          python3 benchmarks/mass_stability.py $MS/${o}_s$GSEED --jobs "${SJOBS:-8}" --out "$OUT/stability_${o}_s$GSEED.json" \
            2>/dev/null | tail -1
        done
        wait  # indoor_room
        echo "[$(elapsed) s] done"
        ;;
    esac
    ;;
  full)  # HEAD=latent|lifted: another material head; LIFT_EVERY=N: lift every N steps as well
    make_scene 2>&1 | tail -5
    python3 -m nerfstudio.scripts.train physgs --data "$SCENE" --max-num-iterations 7000 --vis tensorboard \
      ${HEAD:+--pipeline.model.material-head $HEAD} ${LIFT_EVERY:+--pipeline.lifting-every $LIFT_EVERY} \
      --output-dir /tmp/physgs_runs --timestamp gpu 2>&1 | grep -v Warning | tail -5 | tee "$OUT/full_train.log"
    CFG=$(ls /tmp/physgs_runs/*/physgs/gpu/config.yml)
    python3 -m nerfstudio.scripts.eval --load-config "$CFG" --output-path "$OUT/full_eval.json" 2>&1 | tail -5
    python3 -m physgs_nerfstudio.cli export --load-config "$CFG" --output-dir /tmp/physgs_export 2>&1 | tail -30 \
      | tee "$OUT/full_export.log"
    cp /tmp/physgs_export/report.json "$OUT/full_report.json" 2>/dev/null
    ;;
esac
