#!/usr/bin/env bash
# Installs everything a developer or CI needs: the project (editable) with the simulator,
# test and cluster (Dask) extras, and the few Debian packages the tests use: Chromium (the
# dashboard's screenshot test drives it headless). Root (CI) installs them with apt-get;
# anyone else is told what is missing. Idempotent: what is there is left alone.
set -euo pipefail
cd "$(dirname "$0")/.."

debian_packages=()
command -v chromium >/dev/null 2>&1 || debian_packages+=(chromium)
if ((${#debian_packages[@]})); then
    if [[ $(id -u) -eq 0 ]] && command -v apt-get >/dev/null 2>&1; then
        export DEBIAN_FRONTEND=noninteractive
        apt-get update -qq
        apt-get install -y -qq --no-install-recommends "${debian_packages[@]}" >/dev/null
    else
        echo "install.sh: missing Debian packages: ${debian_packages[*]} (sudo apt-get install ${debian_packages[*]})" >&2
    fi
fi

python -m pip install --upgrade pip
python -m pip install -e ".[sim,test,cluster]"
