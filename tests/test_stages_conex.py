"""The CONEX-AGP driver against the CONEX simulator through a real pseudo-terminal."""

import threading
import time

import pytest

from clholo.tools.stages import (HomingTimeoutError, StageLimitError, StageNotReferencedError,
                                 StageTimeoutError, open_stage)
from clholo.tools.stages.simulators import ConexSimulator

FAST = dict(reply_timeout=0.2, poll=0.005, reset_wait=0.03)


@pytest.fixture
def sim():
    s = ConexSimulator(speedup=400.0, reset_s=4.0)
    yield s
    s.close()


def lines(sim):
    return [n for _, n in sim.received]


def test_home_moves_and_rehoming_needs_reset(sim, rng):
    with open_stage(sim.port, "conex", **FAST) as pupil:
        assert pupil.limits == sim.travel            # asked with SL? / SR?
        assert pupil.state() == (0, "0A")
        pupil.home(timeout=5)
        assert pupil.state()[1] == "32" and pupil.position() == 0.0
        target = float(rng.uniform(-10, 10))
        pupil.move_to(target, timeout=5)
        assert abs(pupil.position() - target) < 1e-5
        step = float(rng.uniform(-2, 2))
        pupil.move_by(step, timeout=5)
        assert abs(pupil.position() - (target + step)) < 1e-4
        assert "1RS" not in lines(sim)
        pupil.home(timeout=5)                          # READY: OR alone would be refused (K)
        assert "1RS" in lines(sim) and pupil.position() == 0.0
        # every action was followed by TE
        sent = lines(sim)
        for i, line in enumerate(sent):
            if line[1:3] in ("OR", "PA", "PR"):
                assert sent[i + 1] == "1TE"


def test_not_referenced_refuses_moves(sim):
    with open_stage(sim.port, "conex", **FAST) as pupil:
        with pytest.raises(StageNotReferencedError, match="home"):
            pupil.move_to(1.0)
        with pytest.raises(ValueError, match="position_mm=20"):
            pupil.move_to(20.0)


def test_stale_bytes_at_open():
    with ConexSimulator(speedup=400.0, stale_bytes=b"1TP9.99\r\n\x00garbage") as sim:
        with open_stage(sim.port, "conex", **FAST) as pupil:
            pupil.home(timeout=5)
            assert pupil.position() == 0.0


def test_garbled_and_dropped_replies(sim):
    with open_stage(sim.port, "conex", **FAST) as pupil:
        pupil.home(timeout=5)
        sim.garble["TP"] = 1
        assert pupil.position() == 0.0
        assert lines(sim).count("1TP") == 2
        sim.drop["TS"] = 1
        assert pupil.state() == (0, "32")
        sim.drop["TP"] = 10**6
        with pytest.raises(StageTimeoutError, match="1TP"):
            pupil.position()
        sim.drop.clear()


def test_homing_that_never_finishes_times_out_and_stops(sim):
    sim.homing_never_finishes = True
    with open_stage(sim.port, "conex", **FAST) as pupil:
        with pytest.raises(HomingTimeoutError, match="homing"):
            pupil.home(timeout=0.3)
        assert "1ST" in lines(sim) and sim.state == "0B"


def test_limit_hit_raises_and_stops(sim):
    with open_stage(sim.port, "conex", **FAST) as pupil:
        pupil.home(timeout=5)
        sim.limit_switch = (-5.0, 2.5)
        with pytest.raises(StageLimitError, match="positive end of run"):
            pupil.move_to(4.0, timeout=5)
        assert "1ST" in lines(sim) and sim.position_mm == 2.5


def test_one_query_outstanding_from_two_threads(sim):
    with open_stage(sim.port, "conex", **FAST) as pupil:
        pupil.home(timeout=5)
        pupil.move_to(1.25, timeout=5)
        results, errors = [], []

        def worker():
            try:
                for _ in range(10):
                    results.append(pupil.position())
            except Exception as exc:  # pragma: no cover - reported below
                errors.append(exc)

        threads = [threading.Thread(target=worker) for _ in range(2)]
        for t in threads:
            t.start()
        for t in threads:
            t.join()
        assert not errors and results == [1.25] * 20
        # no request was written while another waited for its reply
        assert lines(sim).count("1TP") == 20


def test_reset_wait_then_home_from_disable(sim):
    with open_stage(sim.port, "conex", **FAST) as pupil:
        pupil.home(timeout=5)
        sim.limit_switch = (-5.0, 2.5)
        with pytest.raises(StageLimitError):
            pupil.move_to(4.0, timeout=5)
        sim.limit_switch = None
        t = time.monotonic()
        pupil.home(timeout=5)        # DISABLE -> RS, wait, OR
        assert pupil.state()[1] == "32" and time.monotonic() - t < 3


def test_late_reply_is_not_taken_for_the_next_answer(sim):
    with open_stage(sim.port, "conex", **FAST) as pupil:
        pupil.home(timeout=5)
        sim.late_s = 0.3                 # longer than reply_timeout (0.2 s): the driver retries
        sim.late["TP"] = 1
        assert pupil.position() == 0.0
        time.sleep(0.3)                  # the late "1TP0.000000" is now waiting in the port
        sim.position_mm = 1.5
        assert pupil.position() == 1.5   # the stale line was flushed, not read as the answer
