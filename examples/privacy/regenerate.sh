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

# 2. The budget studies (pairs x maximum epochs, one attacker seed), one queue of two jobs. The former table
#    attacker (MLP 256 units, constant learning rate 1e-3; FORMER pins it): lens, fixed and learned LCD at 6x8 and
#    24x32, both learned attacks. It was still rising at 6x8, and its variants below re-identified up to 15 points
#    more; the table's attacker (the defaults) is the one of them all with the lowest validation loss.
study() {  # $1 the file's ending ("" for the table attacker's grid, else -larger or -former...), $2 ENCODER-SIZE,
           # then budget_study.py options; a CSV that exists is kept
    local enc="${2%-*}" size="${2##*-}" f="$W/budget/$2$1.csv"; shift 2
    [ -f "$f" ] || python "$HERE/budget_study.py" --run "$T1/encoder=$enc,embedding=$size,decoder=fcnn,seed=0" \
        --out "$f" --seeds 1 --probes 1000 "$@" > "${f%.csv}.log" 2>&1
}
queue() { "$@" & while [ "$(jobs -r | wc -l)" -ge 2 ]; do sleep 10; done; }
FORMER="--hidden 256 --schedule constant --lr 1e-3 --inputs standardise"
for camera in lens-6x8 fixed_slm-6x8 learned_slm-6x8 lens-24x32 fixed_slm-24x32 learned_slm-24x32; do
    queue study -former "$camera" --attacks learned,learned_conv --pairs 1000,10000,60000 --epochs 5,15,50 $FORMER
done
wait

# 3. The former attacker's variants at all pairs (60,000), on the cameras where it left room (the lens and LCD
#    cameras at 24x32 are re-identified 100 %): four times the maximum epochs (200, the same early stopping); the
#    one-cycle schedule to 3e-3; the MLP four times wider (1024 units; the convolutional decoder four times wider,
#    128 channels, costs about 16 times on a CPU and is left out). The three 6x8 cameras, the coded aperture 24x32.
LONGER="--attacks learned,learned_conv --pairs 60000 --epochs 200 $FORMER"
SCHEDULED="--attacks learned,learned_conv --pairs 60000 --epochs 50 --hidden 256 --schedule one_cycle --lr 3e-3 --inputs standardise"
LARGER="--attacks learned --pairs 60000 --epochs 50 --hidden 1024 --schedule constant --lr 1e-3 --inputs standardise"
for camera in fixed_slm-6x8 learned_slm-6x8 lens-6x8; do queue study -former-longer "$camera" $LONGER; done
for camera in fixed_slm-6x8 learned_slm-6x8 lens-6x8; do queue study -former-scheduled "$camera" $SCHEDULED; done
for camera in fixed_slm-6x8 learned_slm-6x8 lens-6x8 coded_aperture-24x32; do
    queue study -former-larger "$camera" $LARGER
done
wait

# 3b. Is the table's attacker (the defaults) converged? Its MLP over 10,000 and 60,000 pairs x at most 50 and 200
#     epochs (four times its own), and twice as wide (2048 units, 3.1x the weights), on the cameras where the
#     former attacker moved most: the fixed LCD and the lens at 6x8, the coded aperture at 24x32. The same grid
#     with scalar standardisation instead of whitening (-standardised) on the fixed LCD 6x8 and the coded aperture.
for camera in fixed_slm-6x8 coded_aperture-24x32; do
    queue study -standardised "$camera" --attacks learned --pairs 10000,60000 --epochs 50,200 --inputs standardise
done
for camera in fixed_slm-6x8 coded_aperture-24x32 lens-6x8; do
    queue study "" "$camera" --attacks learned --pairs 10000,60000 --epochs 50,200
    queue study -larger "$camera" --attacks learned --pairs 60000 --epochs 50 --hidden 2048
done
wait

# 4. The defences' runs: variable patterns and privacy-aware training, 5 epochs each (examples/privacy/defence.yaml).
optoenc sweep "$HERE/defence.yaml" --out "$W/defence" --workers 2 --threads 1

# 5. The defences against the table's attackers (the defaults), one run a job, two at a time (one attacker seed: a defence run and
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
python "$HERE/make_privacy.py" --table "$W/privacy/all" --cells "$T1" --budget "$W/budget" --defence "$W/defence"
