#!/bin/bash
# Run on the lent GPU machine (no ctrplan install there: PYTHONPATH is the checkout, and
# .gpu/ctr.py holds `from ctrplan.cli.app import main; raise SystemExit(main())`):
#   OUT=DIR bash run.sh cuda 6 2000
# usage: .gpu/run.sh DEVICE MINUTES SMOKE_STEPS   (writes $OUT/all.tgz)
set -u
DEV=$1; MIN=$2; SMOKE=$3
export PYTHONUNBUFFERED=1 PYTHONPATH=$PWD OMP_NUM_THREADS=4 OMP_WAIT_POLICY=PASSIVE
W=/tmp/w; rm -rf $W; mkdir -p $W/m
PY=${PY:-python3}
finish() { cp .gpu/*.sh $W/ 2>/dev/null; tar czf $OUT/all.tgz -C $W . ; ls -la $W $W/m; }
trap finish EXIT
( nvidia-smi --query-gpu=name,memory.total,driver_version --format=csv; nproc; free -g ) > $W/machine.txt 2>&1
$PY -c "import torch,numba,numpy;print(torch.__version__, torch.cuda.is_available(), numba.__version__, numpy.__version__)" | tee -a $W/machine.txt
t0=$(date +%s)
timeout 240 $PY .gpu/ctr.py train --robot examples/robots/two_tube.yaml --name smoke --steps $SMOKE \
  --set dense_configs=5000 --device $DEV --threads 4 --out-dir $W/m --json > $W/smoke.json 2> $W/smoke.log
rc=$?; echo "smoke rc=$rc $(( $(date +%s) - t0 )) s"; tail -5 $W/smoke.log
[ $rc = 0 ] || { echo SMOKE FAILED; tail -40 $W/smoke.log; exit 1; }
D=docs/training/design_robots
run() { name=$1; robot=$2; shift 2
  timeout $(( MIN * 60 + 90 )) $PY .gpu/ctr.py train --robot $robot --name $name --device $DEV --threads 4 \
    --time-limit ${MIN}m --out-dir $W/m --json "$@" > $W/$name.json 2> $W/$name.log
  echo "$name rc=$? $(( $(date +%s) - t0 )) s"; }
run d3 $D/design_3.yaml &
run d3big $D/design_3.yaml --set dense_batch=32768 &
run d1 $D/design_1.yaml &
run d1big $D/design_1.yaml --set dense_batch=32768 &
wait
nvidia-smi > $W/smi_end.txt 2>&1
