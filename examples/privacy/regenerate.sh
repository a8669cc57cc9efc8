#!/usr/bin/env bash
# Regenerate docs/results/privacy.csv and docs/results/privacy/ (docs/privacy.md): the attacks on Table 1's
# cameras, the attackers' budget study and stronger attackers, the defences against the same attackers.
#
#   examples/privacy/regenerate.sh TABLE1_SWEEP WORK_DIR
#
# TABLE1_SWEEP: the folder `optoenc sweep examples/paper/table1.yaml --out TABLE1_SWEEP` trained (its cells keep
# their checkpoints; the learned LCD's masks are read from them). WORK_DIR: where the defence runs, the attack
# tables and the budget CSVs go (resumable: a cell with privacy/privacy.csv, a budget CSV that exists, a
# finished defence run are kept). Two jobs run at a time, one thread each (a 2-core machine).
set -euo pipefail
T1="$1/cells"
W="$2"
HERE="$(cd "$(dirname "$0")" && pwd)"
export OMP_NUM_THREADS=1 MKL_NUM_THREADS=1
mkdir -p "$W/budget"

# 1. Every attack on Table 1's FCNN seed-0 cameras (20 cells), 1,000 probes: one camera a job, two jobs at a
#    time, the slowest (largest embeddings) first; then one table of them all.
A="--attacks admm,pinv,plaintext,learned,learned_conv --count 1000"
mkdir -p "$W/privacy/cells"
for size in 24x32 12x16 6x8 3x4; do
    for enc in lens coded_aperture diffuser fixed_slm learned_slm; do
        cell="encoder=$enc,embedding=$size,decoder=fcnn,seed=0"
        optoenc privacy --sweep "$T1" --match "$cell" --out "$W/privacy/cells/$cell" $A > "$W/privacy/cells/$cell.log" 2>&1 &
        while [ "$(jobs -r | wc -l)" -ge 2 ]; do sleep 10; done
    done
done
wait
optoenc privacy --sweep "$T1" --match '*decoder=fcnn,seed=0' --out "$W/privacy/all" $A > "$W/privacy-all.log" 2>&1

# 2. The budget study (pairs x maximum epochs): lens, fixed and learned LCD at 6x8 and 24x32, one queue of two jobs.
study() {  # $1 the file's suffix ("" for the grid, else -larger, -longer or -scheduled), $2 ENCODER-SIZE, then
           # budget_study.py options; a CSV that exists is kept
    local enc="${2%-*}" size="${2##*-}" f="$W/budget/$2$1.csv"; shift 2
    [ -f "$f" ] || python "$HERE/budget_study.py" --run "$T1/encoder=$enc,embedding=$size,decoder=fcnn,seed=0" \
        --out "$f" --seeds 1 --probes 1000 "$@" > "${f%.csv}.log" 2>&1
}
queue() { "$@" & while [ "$(jobs -r | wc -l)" -ge 2 ]; do sleep 10; done; }
for camera in lens-6x8 fixed_slm-6x8 learned_slm-6x8 lens-24x32 fixed_slm-24x32 learned_slm-24x32; do
    queue study "" "$camera" --attacks learned,learned_conv --pairs 1000,10000,60000 --epochs 5,15,50
done
wait

# 3. Stronger attackers at all pairs, one queue of two jobs, on the cameras whose table attack leaves room (the
#    lens and LCD cameras at 24x32 are re-identified 100 % by the table's attackers, which no attacker can exceed):
#    trained four times longer (at most 200 epochs, the same early stopping); with a learning-rate schedule
#    (one-cycle: warm-up to three times the constant rate, cosine annealing over the 50 epochs); and the MLP four
#    times wider (hidden 1024, at most 50 epochs; the convolutional decoder four times wider, 128 channels, costs
#    about 16 times the table's on a CPU and is left out). The three 6x8 cameras, and the coded aperture at 24x32
#    (wider).
LONGER="--attacks learned,learned_conv --pairs 60000 --epochs 200"
SCHEDULED="--attacks learned,learned_conv --pairs 60000 --epochs 50 --schedule one_cycle --lr 3e-3"
LARGER="--attacks learned --pairs 60000 --epochs 50 --hidden 1024"
for camera in fixed_slm-6x8 learned_slm-6x8 lens-6x8; do queue study -longer "$camera" $LONGER; done
for camera in fixed_slm-6x8 learned_slm-6x8; do queue study -larger "$camera" $LARGER; done
queue study -scheduled fixed_slm-6x8 $SCHEDULED
queue study -scheduled lens-6x8 $SCHEDULED
queue study -larger lens-6x8 $LARGER
queue study -scheduled learned_slm-6x8 $SCHEDULED
queue study -larger coded_aperture-24x32 $LARGER
wait

# 4. The defences' runs: variable patterns and privacy-aware training, 5 epochs each (examples/privacy/defence.yaml).
optoenc sweep "$HERE/defence.yaml" --out "$W/defence" --workers 2 --threads 1

# 5. The defences against the table's attackers, one run a job, two at a time (one attacker seed: a defence run and
#    its baseline share it; each run's table is kept in RUN_DIR/privacy); then the defence table from them.
D="--count 1000 --attack-seeds 1 --attacks admm,admm_search,plaintext,learned,learned_one,learned_conv"
defended() {  # $1 a run directory of the defence sweep
    local name; name="$(basename "$1")"
    optoenc privacy --sweep "$W/defence" --match "$(printf '%s' "$name" | sed 's/\[/[[]/g')" \
        --out "$W/defence/privacy-runs/$name" $D > "$W/defence/privacy-runs/$name.log" 2>&1
}
mkdir -p "$W/defence/privacy-runs"
for run in "$W"/defence/cells/*24x32*/ "$W"/defence/cells/*6x8*/; do queue defended "$run"; done
wait
optoenc privacy --sweep "$W/defence" --defence $D > "$W/privacy-defence.log" 2>&1

# 6. Into docs/results.
python "$HERE/make_privacy.py" --table "$W/privacy/all" --cells "$T1" --budget "$W/budget" --defence "$W/defence/privacy"
