import sys
from pathlib import Path

# toyscene.py (the tests' own ray-cast fixture) sits next to the tests
sys.path.insert(0, str(Path(__file__).resolve().parent))
