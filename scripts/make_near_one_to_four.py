"""Write examples/near_one_to_four.npz: the 5-dof system of tests/helpers/systems.py's near_one_to_four() (modal
frequencies 1, 1.7, 2.3, 3.1, 3.954: mode 4 near 4 x mode 0), for examples/near_one_to_four.toml.

    .venv/bin/python scripts/make_near_one_to_four.py
"""
from __future__ import annotations

import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))

from helpers.systems import near_one_to_four  # noqa: E402
from stepnf_polynomial import save_system  # noqa: E402


def main() -> Path:
    M, K, G, H = near_one_to_four()
    return save_system(ROOT / "examples" / "near_one_to_four.npz", M, K, G, H)


if __name__ == "__main__":
    print(main())
