#!/usr/bin/env bash
# Installs everything a developer or CI needs: the project (editable) with the simulator,
# test and cluster (Dask) extras. No system packages are needed: the figures are drawn with
# matplotlib's Agg backend, not MuJoCo's offscreen renderer, so no GPU or display either.
set -euo pipefail
cd "$(dirname "$0")/.."
python -m pip install --upgrade pip
python -m pip install -e ".[sim,test,cluster]"
