#!/usr/bin/env bash
# Installs everything a developer or CI needs: the project (editable) with the simulator,
# test and cluster (Dask) extras, and the Debian packages the tests and the videos use:
# Chromium (the dashboard's screenshot test drives it headless) and MuJoCo's offscreen
# OpenGL (EGL with Mesa's software driver, OSMesa as the fallback; `m4-sitl fly --video`).
# Root (CI) installs what is missing with apt-get; anyone else is told what is missing.
# Idempotent: what is there is left alone.
set -euo pipefail
cd "$(dirname "$0")/.."

debian_packages=()
for package in chromium libegl1 libegl-mesa0 libgl1-mesa-dri libosmesa6; do
    dpkg-query -W -f='${Status}' "$package" 2>/dev/null | grep -q "ok installed" || debian_packages+=("$package")
done
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
# Byte-compile the project once: with PYTHONDONTWRITEBYTECODE set (as here and in CI) every
# process would otherwise recompile the 2 MB generated dialect (1-3 s per companion/SITL start).
python -m compileall -q m4 companion sitl research analysis >/dev/null
# pymavlink's own tools (mavlogdump.py, MAVExplorer.py, mavproxy.py) decode our messages by name.
python -m m4.mavlink.install_dialect
