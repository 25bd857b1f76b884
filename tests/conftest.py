import sys
from pathlib import Path

# tests/systems.py and friends
sys.path.insert(0, str(Path(__file__).parent))
