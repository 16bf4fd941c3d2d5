"""`python -m granular_multiscale.dem.check_yade`: fail clearly when YADE is not importable."""

import subprocess
import sys

INSTALL_HINT = (
    "YADE is not importable from this Python ({exe}).\n"
    "Install it with:  sudo apt-get install -y yade   and re-run:  bash envs/setup.sh\n"
    "(the set-up puts /usr/lib/x86_64-linux-gnu/yade-double/py on the venv's path)."
)


def yade_version() -> str:
    """Import YADE in a child process (its import prints and rebinds globals) and return its version."""
    code = "import yade.config as c; print(c.version if hasattr(c, 'version') else 'unknown')"
    try:
        out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    except subprocess.TimeoutExpired:
        raise RuntimeError("importing YADE took over 120 s") from None
    if out.returncode != 0:
        raise RuntimeError(INSTALL_HINT.format(exe=sys.executable) + "\n" + out.stderr[-2000:])
    return out.stdout.strip().splitlines()[-1] if out.stdout.strip() else "unknown"


if __name__ == "__main__":
    try:
        print(f"setup: YADE {yade_version()} importable from {sys.executable}")
    except RuntimeError as e:
        print(f"setup: {e}", file=sys.stderr)
        sys.exit(1)
