#!/bin/bash
# jaxpose on a SLURM cluster: fit every depth image of a recording on 4 nodes x 8 GPUs.
#
# One process per GPU (JAX's own SLURM set-up: it reads the coordinator, the process
# count and id, and the GPU of each process from SLURM's variables).  Every process
# reads its share of the inputs (every 32nd, from the same list) and writes its own
# results; the batches run as one program over all 32 GPUs.  Submit again after an
# interruption: --resume skips the results already written.  See docs/scaling.md.
#
#SBATCH --job-name=jaxpose-fit
#SBATCH --nodes=4
#SBATCH --ntasks-per-node=8          # one process per GPU
#SBATCH --gpus-per-node=8            # every GPU visible to every process; JAX picks one by SLURM_LOCALID
#SBATCH --cpus-per-task=8
#SBATCH --time=02:00:00
#SBATCH --output=jaxpose-%j-%t.log

set -euo pipefail
source "$HOME/jaxpose/.venv/bin/activate"   # an install of jaxpose[...] on a file system every node sees

export JAXPOSE_DISTRIBUTED=1                 # join the run when jaxpose is imported
export JAXPOSE_CACHE_DIR="$PWD/.jaxpose-xla" # compiled programs shared by the nodes (optional)

# the inputs and the output folder must be on a file system every node sees
srun jaxpose fit recordings/take1/*.png \
    --skeleton humanoid --background recordings/take1/empty.png \
    --out-dir fits/take1 --resume --batch 16 --quiet

# Without SLURM (or to override it), give the three settings yourself on every host:
#   JAXPOSE_DISTRIBUTED=1 JAX_COORDINATOR_ADDRESS=node0:8476 JAX_NUM_PROCESSES=4 JAX_PROCESS_ID=<0..3> \
#       jaxpose fit ...
