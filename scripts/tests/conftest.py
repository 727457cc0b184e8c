"""pytest set-up of the Python tests: every folder of scripts/ on the import path, so that a test
imports any script by its module name (scripts/crowdrom_io.py and the scripts of scripts/pipeline,
scripts/post, scripts/bench and scripts/dev)."""
import os
import sys

SCRIPTS = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path[:0] = [SCRIPTS] + [os.path.join(SCRIPTS, d) for d in ("pipeline", "post", "bench", "dev")]
