"""The heterogeneous population (&study 'speed_mean', 'speed_spread': each agent's desired speed
uniform on mean +- spread, drawn from the sample's speed_seed component) through the whole
pipeline at test size: ``scripts/run_study.sh`` on the crowd1000_mini scene with the two speed
parameters instead of the exit widths and the common speed (inputs/crowd1000_mini_* otherwise).

* the database stores the components speed_mean, speed_spread, speed_seed; the seeds are
  integers, different per sample;
* each sample's first desired velocities (stored by crowd_snapshots) have per-agent magnitudes
  inside (mean - spread, mean + spread) and really spread (not one common speed);
* the sweep, the ML correction, the figures and the table are made.
"""
import csv
import os
import re
import shutil
import subprocess
import sys

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
import crowdrom_io as cio  # noqa: E402
from test_rom import BIN, ENV, ROOT  # noqa: E402

STUDY = """&study
  n_params = 2, param_name = 'speed_mean', 'speed_spread', param_min = 1.0, 0.1,
  param_max = 1.4, 0.4, sampling = 'random', n_train = 6, n_valid = 2, seed = 15,
  database = 'results/hetero_mini_snapshots.h5'
/"""
SWEEP = """&sweep
  n = 10, 20, r = 15, 30, hyper = 'eq', 'eq', contacts = 'cone', 'cone'
/"""


def make_case(tmp):
    (tmp / "inputs").mkdir()
    for suffix in ("_study.nml", "_rom.nml", "_ml.json"):
        text = open(os.path.join(ROOT, "inputs", "crowd1000_mini" + suffix)).read()
        text = text.replace("crowd1000_mini", "hetero_mini")
        if suffix == "_study.nml":
            text = re.sub(r"&study\b.*?\n/", STUDY, text, flags=re.S)
            text = text.replace("n_steps = 70", "n_steps = 40")
        if suffix == "_rom.nml":
            text = re.sub(r"&sweep\b.*?\n/", SWEEP, text, flags=re.S)
        (tmp / "inputs" / ("hetero_mini" + suffix)).write_text(text)


def test_hetero_pipeline(tmp_path):
    make_case(tmp_path)
    env = dict(ENV, CROWDROM_BIN=BIN, CROWDROM_WORK=str(tmp_path), NP="2")
    p = subprocess.run([os.path.join(ROOT, "scripts", "run_study.sh"), "hetero_mini"], cwd=tmp_path,
                       capture_output=True, text=True, env=env)
    assert p.returncode == 0, p.stdout[-4000:] + p.stderr[-4000:]
    res = tmp_path / "results"
    with cio.open_h5(str(res / "hetero_mini_snapshots.h5"), cio.DB_SCHEMA) as f:
        meta = cio.read_database_meta(f)
        assert meta["param_names"] == ["speed_mean", "speed_spread", "speed_seed"]
        for s in ("train", "valid"):
            mu = cio.read_database_set(f, s, velocities=False)["params"]
            v1 = cio.read_database_desired(f, s)[:, 0, :]
            seeds = mu[:, 2]
            assert np.all(seeds == np.round(seeds)) and np.all(seeds >= 0) and len(set(seeds)) == len(seeds)
            for (m, sp, _), v in zip(mu, v1):
                c = np.hypot(v[0::2], v[1::2])
                assert np.all(c > m - sp - 1e-12) and np.all(c < m + sp + 1e-12), (m, sp, c.min(), c.max())
                assert c.max() - c.min() > sp, (sp, c.min(), c.max())
    rows = list(csv.DictReader(open(res / "hetero_mini_table.csv")))
    assert {r["set"] for r in rows} == {"train", "valid"}
    assert (res / "hetero_mini_ml.h5").exists()
    figs = res / "hetero_mini_figures"
    for name in ("evac/evac_curves.png", "evac/t90_map.png", "tradeoff.png", "pod_decay.png"):
        assert (figs / name).stat().st_size > 1000, name
    assert "=== run_study [hetero_mini] stage 6 of 7" in p.stdout
    assert "=== run_study [hetero_mini] stage 7 of 7: skipped" in p.stdout
