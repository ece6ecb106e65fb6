import subprocess
import sys
import textwrap
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def test_every_companion_module_imports_without_the_sim_extra():
    """What `pip install .` gives the robot: no MuJoCo, no matplotlib; every companion module loads."""
    script = textwrap.dedent("""
        import importlib, pkgutil, sys
        import importlib.abc

        class NoSimExtra(importlib.abc.MetaPathFinder):
            def find_spec(self, name, path=None, target=None):
                if name.split(".")[0] in ("mujoco", "matplotlib"):
                    raise ImportError(f"{name} is not installed on the robot")
                return None

        sys.meta_path.insert(0, NoSimExtra())
        import companion
        for module in pkgutil.walk_packages(companion.__path__, "companion."):
            importlib.import_module(module.name)
        print("ok")
    """)
    result = subprocess.run([sys.executable, "-c", script], cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert result.returncode == 0 and result.stdout.strip() == "ok", result.stderr[-2000:]
