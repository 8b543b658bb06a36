#!/usr/bin/env bash
# One GPU session's measurements, in two parts that each fit a 10-minute command (see benchmarks/README.md).
#   bash benchmarks/gpu/run_gpu.sh kernels   # rasterizer parity, lifting, mass integration, GPU tests
#   [ROUNDS=3] bash benchmarks/gpu/run_gpu.sh training  # physgs vs splatfacto-big (ROUNDS pairs, A B A B ...)
#   BASE=../other_checkout bash benchmarks/gpu/run_gpu.sh perf  # issue 13: exports before/after
#   bash benchmarks/gpu/run_gpu.sh perf-training                  # issue 13: training cost on the same scene
#   SEEDS="404 505" bash benchmarks/gpu/run_gpu.sh suite          # issue 12: CPU mass suite + gsplat build
#   [REPEAT=2] [ROUNDS=0] bash benchmarks/gpu/run_gpu.sh interleaved  # issue 13: the training ratio, one process
#   [ROUNDS=2] bash benchmarks/gpu/run_gpu.sh variants  # issue 13: the training step, physgs's pieces swapped one at a time
#   bash benchmarks/gpu/run_gpu.sh mem       # issue 13: memory and iteration cost of the material heads (chair)
#   HEAD=lifted bash benchmarks/gpu/run_gpu.sh full   # the full run with another material head
#   BASE=.export_base bash benchmarks/gpu/run_gpu.sh export  # issues 12+13: full chair run, its mass, exports before/after
#                                            # (TIMELINE=N: then N mass exports timed function by function)
#                                            # (MID=NAME=DIR: a third tree between them)
#   OBJECTS=5 STEPS=3000 bash benchmarks/gpu/run_gpu.sh batch     # issue 14: physgs batch (local) over the suite
#   bash benchmarks/gpu/run_gpu.sh geometry  # issue 12: full chair run, geometry vs ground truth (geometry_diag.py)
#   OBJECTS="table stool" bash benchmarks/gpu/run_gpu.sh gsuite  # issue 12: the same for other generated objects
#   bash benchmarks/gpu/run_gpu.sh mprofile  # issue 13: profile of `physgs export --outputs mass` on the chair
#   PHASE=scenes CPU_SEEDS="1313 1414" bash benchmarks/gpu/run_gpu.sh msuite  # issue 12: GPU suite scenes (+ CPU suite)
#   PHASE=train OBJECTS="mug chair" bash benchmarks/gpu/run_gpu.sh msuite     # ... then train and score them
#   PHASE=diag [RULES="expected median"] [ACCOUNT="top"] bash benchmarks/gpu/run_gpu.sh msuite  # ... carving rules vs the truth
#   PHASE=seams OBJECTS="shoe hammer mug pan bottle lamp" bash benchmarks/gpu/run_gpu.sh msuite  # ... the seams vs the truth
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
case "${1:-}" in perf|suite|mem|variants|export|batch|geometry|gsuite|mprofile|msuite) export GSPLAT_BUILD_LATER=1 ;; esac  # compiled beside CPU work
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
  profile)  # [WARMUP=N] [METHODS="..."]: the profiled 40 steps start at step N
    make_scene 2>&1 | tail -3
    (cd benchmarks/gpu && python3 profile_training.py --data "$SCENE" --warmup "${WARMUP:-300}" ${METHODS:+--methods $METHODS}) 2>&1 | grep -v Warning \
      > "$OUT/profile.txt"; tail -5 "$OUT/profile.txt"
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
  interleaved)
    # issue 13: physgs vs splatfacto-big trained in one process, blocks of steps in turn (bench_interleaved.py);
    # REPEAT processes of it, then (ROUNDS > 0) bench_training.py's isolated pairs for comparison
    make_scene 2>&1 | tail -3 | tee "$OUT/scene.log"
    for i in $(seq "${REPEAT:-2}"); do
      python3 benchmarks/gpu/bench_interleaved.py --data "$SCENE" --warmup 300 --steps "${TRAIN_STEPS:-1500}" \
        --methods ${METHODS:-splatfacto-big physgs physgs+device_sizes} --out "$OUT/interleaved_$i.json" 2>&1 \
        | grep -v Warning | tee "$OUT/interleaved_$i.log" | tail -4
      echo "[$(elapsed) s] interleaved $i"
    done
    if [ "${ROUNDS:-0}" -gt 0 ]; then
      python3 benchmarks/gpu/bench_training.py --data "$SCENE" --steps 1500 --warmup 300 --rounds "$ROUNDS" \
        --out "$OUT/training.json" 2>&1 | grep -v Warning | tee "$OUT/training.log" | tail -3
    fi
    echo "[$(elapsed) s] done"
    ;;
  variants)
    # issue 13: where physgs's training step loses time against splatfacto-big (step_variants.py), on the chair scene
    make_scene 2>&1 | tail -3 | tee "$OUT/scene.log"
    wait  # the gsplat build (setup_env.sh with GSPLAT_BUILD_LATER=1), beside the scene
    echo "[$(elapsed) s] scene; gsplat: $(cat "$OUT/gsplat_build.txt" 2>/dev/null)"
    tar czf "$OUT/gsplat_cuda.tgz" -C .gsplat_build gsplat_cuda/gsplat_cuda.so gsplat_cuda/physgs_build_stamp.json 2>/dev/null
    python3 benchmarks/gpu/step_variants.py --data "$SCENE" --rounds "${ROUNDS:-2}" --warmup 300 \
      --steps "${TRAIN_STEPS:-700}" ${VARIANTS:+--variants $VARIANTS} --out "$OUT/step_variants.json" 2>&1 \
      | grep -v Warning | tee "$OUT/step_variants.log" | tail -8
    echo "[$(elapsed) s] done"
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
    for i in $(seq 1 "${TIMELINE:-0}"); do  # TIMELINE=N: N fresh mass exports, function by function (export_timeline.py)
      TIMELINE_JSON="$OUT/mass_timeline_$i.json" python3 benchmarks/export_timeline.py --load-config "$CFG" \
        --output-dir /tmp/physgs_tl --outputs mass --overwrite ${TIMELINE_ARGS:-} 2>&1 | grep -v Warning > "$OUT/mass_timeline_$i.txt"
      grep -A200 "^import torch" "$OUT/mass_timeline_$i.txt" | head -70
    done
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
  geometry)
    # issue 12 (about 6-7 minutes on an H100): the chair scene (60 views at 512 px), `ns-train physgs` (STEPS, 7000),
    # with USER_EXPORT=1 the user's `physgs export --outputs mass`, then benchmarks/geometry_diag.py for this tree's
    # geometry and the baseline's (DIAG_VARIANTS): selection, masks and carving vs the generator's ground truth,
    # mass, and a compact copy of the splat (splat.npz; DUMP= for none); SUITE_SEEDS: the CPU suite beside it
    STEPS=${STEPS:-7000}
    # (the device returns 8 files: the logs go to stdout; the dump holds the dataparser transform)
    make_scene 2>&1 | tail -3
    wait  # the gsplat build
    echo "[$(elapsed) s] scene; gsplat: $(cat "$OUT/gsplat_build.txt" 2>/dev/null)"
    if [ -n "${SUITE_SEEDS:-}" ]; then  # the CPU mass suite at these seeds on the spare cores, beside the training,
      # then re-exported with the baseline geometry (no hull test, no mask completion) for a side-by-side comparison
      (CUDA_VISIBLE_DEVICES= python3 benchmarks/mass_suite.py --seeds $SUITE_SEEDS --jobs "${JOBS:-12}" \
        --out /tmp/mass_suite > "$OUT/mass_suite.log" 2>&1; cp /tmp/mass_suite/mass_suite.json "$OUT/" 2>/dev/null
       CUDA_VISIBLE_DEVICES= python3 benchmarks/mass_suite.py --seeds $SUITE_SEEDS --jobs "${JOBS:-12}" --out \
        /tmp/mass_suite --alt-name baseline --export-args="--mass.geometry.select.hull-vote-fraction 2 \
        --mass.geometry.no-complete-masks" > "$OUT/mass_suite_baseline.log" 2>&1
       cp /tmp/mass_suite/mass_suite_baseline.json "$OUT/" 2>/dev/null; echo "[$(elapsed) s] suite done") &
      SUITE_PID=$!
    fi
    python3 -m nerfstudio.scripts.train physgs --data "$SCENE" --max-num-iterations "$STEPS" --vis tensorboard \
      --steps-per-eval-image 100000000 --steps-per-eval-all-images 100000000 --steps-per-save "$STEPS" \
      --output-dir /tmp/physgs_runs --timestamp gpu 2>&1 | grep -v Warning | tail -4
    CFG=$(ls /tmp/physgs_runs/*/physgs/gpu/config.yml)
    if [ -n "${USER_EXPORT:-}" ]; then  # USER_EXPORT=1: the user's `physgs export --outputs mass` as well
      echo "[$(elapsed) s] trained; physgs export --outputs mass"
      python3 -m physgs_nerfstudio.cli export --load-config "$CFG" --output-dir /tmp/physgs_export --outputs mass \
        > "$OUT/full_export.log" 2>&1; tail -25 "$OUT/full_export.log"
      cp /tmp/physgs_export/report.json "$OUT/full_report.json" 2>/dev/null
    fi
    for variant in ${DIAG_VARIANTS:-default baseline}; do  # this tree's geometry, and the baseline's
      echo "[$(elapsed) s] geometry_diag $variant"
      FLAGS=$([ "$variant" = baseline ] && echo "--baseline --tag _baseline" || echo "${DUMP-"--dump"}")
      PYTHONUNBUFFERED=1 timeout $((${LIMIT:-575} - $(elapsed))) python3 benchmarks/geometry_diag.py --load-config \
        "$CFG" --out "$OUT" $FLAGS 2>&1 | grep --line-buffered "^\[\|object:\|wrote\|summary\|Error\|error"
    done
    if [ -n "${SUITE_PID:-}" ]; then  # until the suite ends or the time is up (its log has every finished row)
      while kill -0 "$SUITE_PID" 2>/dev/null && [ $(elapsed) -lt ${LIMIT:-575} ]; do sleep 5; done
      tail -n 1 "$OUT/mass_suite.log" "$OUT/mass_suite_baseline.log" 2>/dev/null
    fi
    echo "[$(elapsed) s] done"
    ;;
  gsuite)
    # issue 12 (about 4-5 minutes per object on an H100): generated OBJECTS at 60 views 512 px (scenes made in
    # parallel on the CPUs), then per object `ns-train physgs` (STEPS, 7000) and geometry_diag.py (this tree's
    # geometry; BASELINE=1: the baseline's as well) -> geometry_diag_<object>.json; stops before LIMIT
    STEPS=${STEPS:-7000} LIMIT=${LIMIT:-575}
    for o in ${OBJECTS:?OBJECTS="table stool"}; do
      (python3 -m physgs_nerfstudio.cli synth --out /tmp/gs_$o --object $o --views 60 --resolution 512 --overwrite \
         > /dev/null 2>&1 && python3 -m physgs_nerfstudio.cli perceive --data /tmp/gs_$o --vlm simulated \
         --segmenter builtin --no-progress --max-concurrency 8 > /dev/null 2>&1; echo "[$(elapsed) s] scene $o") &
    done
    wait
    for o in $OBJECTS; do
      [ $(elapsed) -gt $((LIMIT - 200)) ] && { echo "[$(elapsed) s] no time left for $o"; break; }
      python3 -m nerfstudio.scripts.train physgs --data /tmp/gs_$o --max-num-iterations "$STEPS" --vis tensorboard \
        --steps-per-eval-image 100000000 --steps-per-eval-all-images 100000000 --steps-per-save "$STEPS" \
        --output-dir /tmp/gs_runs_$o --timestamp gpu 2>&1 | grep "train_iteration"
      CFG=$(ls /tmp/gs_runs_$o/*/physgs/gpu/config.yml) || continue
      for variant in default ${BASELINE:+baseline}; do
        FLAGS=$([ "$variant" = baseline ] && echo "--baseline --tag _${o}_baseline" || echo "--tag _$o")
        echo "[$(elapsed) s] geometry_diag $o $variant"
        PYTHONUNBUFFERED=1 timeout $((LIMIT - $(elapsed))) python3 benchmarks/geometry_diag.py --load-config "$CFG" \
          --out "$OUT" $FLAGS 2>&1 | grep --line-buffered "object:\|summary\|Error\|error"
      done
    done
    echo "[$(elapsed) s] done"
    ;;
  mprofile)
    # issue 13 (about 7 minutes on an H100): where `physgs export --outputs mass` spends its time. The chair scene,
    # `ns-train physgs` (STEPS, default 7000), the export timed twice from outside, then once under cProfile with
    # CUDA_LAUNCH_BLOCKING=1 (each kernel charged to the Python call that launched it); the stamped gsplat build
    # is returned in $OUT/gsplat_cuda for later calls (carry it as .gsplat_build/gsplat_cuda)
    STEPS=${STEPS:-7000}
    make_scene 2>&1 | tail -3
    wait  # the gsplat build
    echo "[$(elapsed) s] scene; gsplat: $(cat "$OUT/gsplat_build.txt" 2>/dev/null)"
    mkdir -p "$OUT/gsplat_cuda"; cp .gsplat_build/gsplat_cuda/gsplat_cuda.so .gsplat_build/gsplat_cuda/physgs_build_stamp.json \
      "$OUT/gsplat_cuda/" 2>/dev/null
    python3 -m nerfstudio.scripts.train physgs --data "$SCENE" --max-num-iterations "$STEPS" --vis tensorboard \
      --steps-per-eval-image 100000000 --steps-per-eval-all-images 100000000 --steps-per-save "$STEPS" \
      --output-dir /tmp/physgs_runs --timestamp gpu 2>&1 | grep -v Warning | tail -3
    CFG=$(ls /tmp/physgs_runs/*/physgs/gpu/config.yml)
    for i in 1 2; do
      echo "[$(elapsed) s] physgs export --outputs mass ($i)"
      /usr/bin/time -f "wall %e s" python3 -m physgs_nerfstudio.cli export --load-config "$CFG" --output-dir /tmp/pm \
        --outputs mass --overwrite > "$OUT/mass_export_$i.log" 2>&1; tail -2 "$OUT/mass_export_$i.log"
    done
    cp /tmp/pm/report.json "$OUT/mass_report.json" 2>/dev/null
    PHYSGS_NO_FAST_EXIT=1 CUDA_LAUNCH_BLOCKING=1 python3 -m cProfile -o /tmp/mass.prof -m physgs_nerfstudio.cli export --load-config "$CFG" \
      --output-dir /tmp/pm --outputs mass --overwrite > /dev/null 2>&1
    python3 -c "import pstats; p = pstats.Stats('/tmp/mass.prof'); p.sort_stats('cumulative').print_stats(90); \
p.sort_stats('tottime').print_stats(40)" > "$OUT/mass_profile.txt" 2>&1
    grep -E "reconstruct|select_object|lift_masks|render_depth|carve|part_|voxel_mixture|fuse_structure|integrate|pi\)|load_run" \
      "$OUT/mass_profile.txt" | head -40
    echo "[$(elapsed) s] done"
    ;;
  after)
    # issue 13, a second call on the machine that ran `export` (its scene, run and gsplat build are still there):
    # benchmarks/mass_integration.py at 1M Gaussians, the run's ns-eval (material accuracy on held-out views), and
    # physgs vs splatfacto-big (bench_training.py, each in its own process) on the same scene
    python3 benchmarks/mass_integration.py --gaussians ${GAUSSIANS:-1000000} --views 54 --size 512 \
      --out "$OUT/mass_integration.json" 2>&1 | tee "$OUT/mass_integration.log" | tail -12
    if [ -n "${BASE:-}" ]; then  # BASE: the same benchmark of that tree, then this tree's again (side by side)
      (cd "$BASE" && python3 benchmarks/mass_integration.py --gaussians ${GAUSSIANS:-1000000} --views 54 --size 512 \
        --out "$OUT/mass_integration_base.json" 2>&1 | tail -9)
      python3 benchmarks/mass_integration.py --gaussians ${GAUSSIANS:-1000000} --views 54 --size 512 \
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
    #     hold indoor_room: it is measured by indoor_room.py --run (-> indoor_room_gpu_sGSEED_V.json for each V in
    #     ROOM_VARIANTS, default "default": the export's selection; "noband", "nosplit", "coarse": without the contact
    #     band, without the split over the support plane, without both; "nohalf", "half8": the hidden space's open
    #     half off, or at 8; "passes8": its rules run up to 8 times; "whole": whole voxels, no partial volume;
    #     "splitband": the split over the floor linked through its contact band, as before session 39; "names1":
    #     perception's object names drop what another object's name claims, SelectConfig.object_names = 1; "band0",
    #     "band05": GeometryConfig.hidden_skin_band 0 or 0.5 voxel), not the
    #     suite; ROOM_TRUTH=1: its export's counted volume against the truth too (voxel_truth.py --volume
    #     --relative-to top -> voxel_truth_room_gpu_sGSEED.json) and its hidden-space stage (hidden_stage.py, left in
    #     $MS/indoor_room_sGSEED/hidden_stage.npz). GPU0=k: the first training goes to GPU k (several invocations side by side).
    #     STABILITY="chair table": then mass_stability.py on those runs (SJOBS = 8 at a time) ->
    #     stability_OBJECT_sGSEED.json; SEAMS="shoe ...": then seam_offset.py on those -> seam_offset_gpu_sGSEED.json
    #   MS=DIR (default /tmp/ms): the folder of the scenes and runs (two variants side by side); SEG_ARGS: perception's
    #     segmenter flags in PHASE=scenes (default "segmenter:builtin", e.g. "segmenter:builtin --segmenter.thin-chroma 4")
    GSEED=${GSEED:-1515} STEPS=${STEPS:-7000} CONC=${CONC:-6} MS=${MS:-/tmp/ms}
    SEG_ARGS=${SEG_ARGS:-segmenter:builtin}
    OBJECTS=${OBJECTS:-"mug chair hammer bottle shoe table pan lamp crate stool dumbbell vase"}
    RUNS=$(for o in $OBJECTS; do [ -d $MS/${o}_s$GSEED/runs ] && echo $MS/${o}_s$GSEED; done)  # diag, seams
    case "${PHASE:?PHASE=scenes|train|diag|seams}" in
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
        # the gsplat build first: six trainings started beside it each found no gsplat_cuda.so (seed 3939)
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
          for v in ${ROOM_VARIANTS:-default}; do  # ROOM_VARIANTS="default noband nosplit coarse": the selection's options
            r=$MS/room_s${GSEED}_$v
            case $v in noband) args="--contact-band none" ;; nosplit) args="--no-split" ;;
                       coarse) args="--contact-band none --no-split" ;; nohalf) args="--open-half none" ;;
                       half8) args="--open-half 8" ;; passes8) args="--passes 8" ;;
                       whole) args="--subsamples 1" ;; splitband) args="--split-in-band" ;;
                       names1) args="--object-names 1" ;; band0) args="--skin-band 0" ;;
                       band05) args="--skin-band 0.5" ;; *) args="" ;; esac
            (python3 benchmarks/indoor_room.py --run $MS/indoor_room_s$GSEED --out $r $args > $r.log 2>&1
             cp $r/indoor_room.json "$OUT/indoor_room_gpu_s${GSEED}_$v.json"
             echo "[$(elapsed) s] indoor_room s$GSEED $v: $(grep -E '"volume_ratio"|"selected_on_ground"' $r/indoor_room.json | tr -d '\n ')") &
          done
          if [ -n "${ROOM_TRUTH:-}" ]; then  # the export's counted volume against the truth, voxel by voxel, about the top
            (d=$MS/indoor_room_s$GSEED; cfg=$(ls $d/runs/*/*/*/config.yml | head -1)
             python3 -m physgs_nerfstudio.cli export --load-config $cfg --outputs mass voxels --output-dir $d/export_truth \
               > $d/export_truth.log 2>&1
             python3 benchmarks/voxel_truth.py $d/export_truth --object indoor_room --seed $GSEED --volume --relative-to top \
               --transforms $(dirname $cfg)/dataparser_transforms.json --out "$OUT/voxel_truth_room_gpu_s$GSEED.json" \
               > $d/voxel_truth.txt 2>&1
             echo "[$(elapsed) s] voxel_truth s$GSEED:"; grep -A14 "counted volume" $d/voxel_truth.txt | grep -v "true  *0.0\| chair\| crate\| lamp"
             python3 benchmarks/hidden_stage.py --run $d --out $d/hidden_stage.npz > $d/hidden_stage.log 2>&1
             echo "[$(elapsed) s] hidden stage s$GSEED: $(tail -1 $d/hidden_stage.log)") &
          fi
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
          python3 benchmarks/mass_stability.py $MS/${o}_s$GSEED --jobs "${SJOBS:-8}" 2>&1 | grep "largest change"
          cp $MS/${o}_s$GSEED/mass_stability.json "$OUT/stability_${o}_s$GSEED.json" 2>/dev/null
        done
        if [ -n "${SEAMS:-}" ]; then
          python3 benchmarks/seam_offset.py $(for o in $SEAMS; do echo $MS/${o}_s$GSEED; done) --trained \
            --out "$OUT/seam_offset_gpu_s$GSEED.json" 2>&1 | grep -v -i warn | tail -3
        fi
        wait  # indoor_room
        echo "[$(elapsed) s] done"
        ;;
      seams)  # the trained runs of OBJECTS: where the export puts the seams between parts (benchmarks/seam_offset.py)
        timeout $((${LIMIT:-570} - $(elapsed))) python3 benchmarks/seam_offset.py $RUNS --trained \
          --out "$OUT/seam_offset_gpu_s$GSEED.json" 2>&1 | grep -v -i warn | tail -30
        echo "[$(elapsed) s] done"
        ;;
      diag)  # the trained runs of OBJECTS against the truth: carving RULES side by side and the export's parts
        # (benchmarks/carve_diag.py --parts; ACCOUNT="top leg_0": the per-view account of those true parts'
        # lost voxels; "baseline" is the export's own rule) -> carve_diag_gpu_s$GSEED.json
        PYTHONUNBUFFERED=1 timeout $((${LIMIT:-570} - $(elapsed))) python3 benchmarks/carve_diag.py $RUNS --parts \
          ${NO_MEDIAN:+--no-median} ${ACCOUNT:+--account $ACCOUNT} \
          --rules ${RULES:-baseline median median_extent1 nodepth} --out "$OUT/carve_diag_gpu_s$GSEED.json" 2>&1 \
          | grep -v -i warn | cut -c1-400
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
