#!/usr/bin/env bash
# Installs everything a developer or CI needs: the project (editable) with the simulator
# and test extras. No system packages are needed: MuJoCo's offscreen rendering is not used
# by the tests.
set -euo pipefail
cd "$(dirname "$0")/.."
python -m pip install --upgrade pip
python -m pip install -e ".[sim,test]"
