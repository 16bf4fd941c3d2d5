"""Progress lines while a long DEM trial runs (the heartbeat of ``executors.call_all``).

A trial with a large strain increment keeps the RVE hosts busy for minutes before they answer;
the driver must keep saying how far they are (RVEs done, DEM steps done of planned, elapsed
time), and doing so must not change a bit of the answer. Here a small increment imposed over
many DEM steps (a high ``min_steps``) makes a trial of a few seconds, and the heartbeat beats
every 0.5 s instead of every 30 s.
"""

from __future__ import annotations

import logging
import math
import re
import time

import numpy as np
import pytest
from dem_fixtures import SETTINGS, packing

from granular_multiscale.dem.executors import HEARTBEAT_INTERVAL
from granular_multiscale.dem.material import DemMaterialPointSet
from granular_multiscale.dem.worker import steps_for_increment

pytestmark = [pytest.mark.slow, pytest.mark.needs_yade]  # runs YADE

# ~2 s of stepping for the busier host on this machine kind (100 spheres, ~80 µs per step)
LONG = dict(SETTINGS, min_steps=20000)
INTERVAL = 0.5
LINE = re.compile(r"DEM trial 1 of this load step (running|done): (\d+)/(\d+) RVEs, ([\d,]+)/([\d,?]+) DEM steps, "
                  r"(\d+)/(\d+) hosts answered, ([\d.]+) s")


def _increment() -> np.ndarray:
    """Four points on two hosts (0, 2 | 1, 3); point 3 gets no increment, so 3 RVEs are stepped."""
    de = np.zeros((4, 6))
    de[:, 2] = -2e-3
    de[1, 0], de[2, 5] = 1e-3, 5e-4
    de[3] = 0.0
    return de


def _beats(caplog, name: str) -> list[tuple]:
    """(state, rves done, rves total, steps done, steps planned, hosts answered, hosts, elapsed) per line."""
    out = []
    for record in caplog.records:
        if record.name == name and (m := LINE.search(record.getMessage())):
            state, *numbers = m.groups()
            values = [None if v == "?" else float(v.replace(",", "")) for v in numbers]
            out.append((state, *values))
    return out


def _check_beats(beats: list[tuple], rves: int, steps: int, hosts: int) -> None:
    running = [b for b in beats if b[0] == "running"]
    assert len(running) >= 2, beats
    assert beats[-1][0] == "done" and [b[0] for b in beats].count("done") == 1, beats
    for column in (1, 3, 5, 7):  # RVEs done, steps done, hosts answered, elapsed: never backwards
        values = [b[column] for b in beats]
        assert values == sorted(values), (column, beats)
    assert all(b[2] <= rves for b in beats) and all(b[4] in (None, steps) for b in beats), beats
    assert beats[-1][1:7] == (rves, rves, steps, steps, hosts, hosts), beats
    assert running[0][1] < rves and running[0][3] < steps  # the first beat came while the hosts were busy


def test_heartbeat_reports_progress_and_changes_no_bit(tmp_path_factory, caplog):
    path, summary = packing(tmp_path_factory)
    de = _increment()
    n = steps_for_increment(de[0], summary["timestep"], LONG["strain_rate"], LONG["min_steps"], LONG["max_steps"])
    assert n == LONG["min_steps"]  # every stepped RVE runs min_steps (+ 1 at rest)
    planned = 3 * (n + 1)
    name = "test_dem_heartbeat"
    caplog.set_level(logging.INFO, logger=name)
    assert DemMaterialPointSet.heartbeat_interval == HEARTBEAT_INTERVAL == 30.0  # the default
    with DemMaterialPointSet(4, [path], LONG, n_workers=2, logger=logging.getLogger(name)) as m:
        m.heartbeat_interval = INTERVAL
        caplog.clear()
        stress, tangent = m.evaluate(de)
        beats = _beats(caplog, name)
        for record in caplog.records:
            print(record.getMessage())
        _check_beats(beats, rves=3, steps=planned, hosts=2)
        assert m._step["particle_steps"] == planned * summary["n_spheres"]
        # the same trial again, without heartbeat: the same bits, and no line
        m.rollback()
        m.heartbeat_interval = math.inf
        caplog.clear()
        quiet_stress, quiet_tangent = m.evaluate(de)
        assert not _beats(caplog, name)
    assert np.array_equal(stress, quiet_stress) and np.array_equal(tangent, quiet_tangent)


def test_dask_heartbeat(tmp_path_factory, caplog):
    """The Dask executor reads the same progress words through an async actor method."""
    from distributed import Client, LocalCluster

    path, _ = packing(tmp_path_factory)
    de = _increment()
    name = "test_dem_heartbeat.dask"
    caplog.set_level(logging.INFO, logger=name)
    settings = dict(SETTINGS, min_steps=12000)
    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None) as cluster, \
            Client(cluster) as client:
        with DemMaterialPointSet(4, [path], settings, n_workers=2, executor="dask", dask_client=client,
                                 logger=logging.getLogger(name)) as m:
            m.heartbeat_interval = INTERVAL
            caplog.clear()
            stress, _ = m.evaluate(de)
            beats = _beats(caplog, name)
            for record in caplog.records:
                if record.name == name:
                    print(record.getMessage())
    _check_beats(beats, rves=3, steps=3 * (settings["min_steps"] + 1), hosts=2)
    with DemMaterialPointSet(4, [path], settings, n_workers=2) as local:  # the local pool, no heartbeat
        local.heartbeat_interval = math.inf
        assert np.array_equal(local.evaluate(de)[0], stress)


def test_a_load_step_of_many_short_trials_beats_too(tmp_path_factory, caplog):
    """The heartbeat's clock runs over the load step, not over one trial: a step whose Newton
    trials are each shorter than the interval still logs a line once the interval has passed."""
    path, _ = packing(tmp_path_factory)
    name = "test_dem_heartbeat_step"
    caplog.set_level(logging.INFO, logger=name)
    trial = re.compile(r"DEM trial (\d+) of this load step (running|done)")
    with DemMaterialPointSet(4, [path], SETTINGS, n_workers=2, logger=logging.getLogger(name)) as m:
        m.heartbeat_interval = math.inf
        t0 = time.perf_counter()
        m.evaluate(_increment() * 0.1)
        one_trial = time.perf_counter() - t0
        m.heartbeat_interval = 2.5 * one_trial  # longer than a trial, shorter than the 10 below
        caplog.clear()
        for k in range(2, 12):
            m.evaluate(_increment() * 0.1 * k)
        numbers = [int(match.group(1)) for r in caplog.records if (match := trial.search(r.getMessage()))]
        assert numbers and min(numbers) >= 2, (one_trial, [r.getMessage() for r in caplog.records])
