"""The APT driver against the APT simulator through a real pseudo-terminal, faults included."""

import time

import numpy as np
import pytest

from clholo.tools.stages import (HomingTimeoutError, StageLimitError, StageNotReferencedError,
                                 StageTimeoutError, open_stage)
from clholo.tools.stages.apt import COUNTS_PER_MM_Z8
from clholo.tools.stages.simulators import AptSimulator

FAST = dict(reply_timeout=0.2, poll=0.01, purge_dwell=0.005)


@pytest.fixture
def sim():
    s = AptSimulator(speedup=400.0)
    yield s
    s.close()


def names(sim):
    return [n for _, n in sim.received]


def settle(sim, count, timeout=1.0):
    """Wait until the simulator has read ``count`` requests (its thread runs behind ours)."""
    deadline = time.monotonic() + timeout
    while len(sim.received) < count and time.monotonic() < deadline:
        time.sleep(0.005)


def test_start_up_sequence_home_and_moves(sim, rng):
    with open_stage(sim.port, "apt", **FAST) as z:
        settle(sim, 3)
        assert names(sim)[:3] == ["HW_NO_FLASH_PROGRAMMING", "HW_REQ_INFO",
                                  "MOD_SET_CHANENABLESTATE"]
        assert z.info.model == "KDC101" and z.info.serial == sim.serial_number
        assert sim.enabled and sim.flash_programming_off
        z.home(timeout=5)
        assert sim.homed and z.position() == 0.0
        for target in rng.uniform(0.5, 24.5, size=3):
            z.move_to(target, timeout=5)
            assert abs(z.position() - target) <= 1 / COUNTS_PER_MM_Z8
            assert abs(sim.position_mm - target) <= 1 / COUNTS_PER_MM_Z8
        before = z.position()
        step = float(rng.uniform(-0.4, 0.4))
        z.move_by(step, timeout=5)
        assert abs(z.position() - (before + step)) <= 2 / COUNTS_PER_MM_Z8
        assert not z.is_moving()


def test_counts_per_mm_is_the_configured_one(rng):
    # the simulator's encoder has the older 34304 counts/mm; the driver configured the same
    with AptSimulator(speedup=400.0, counts_per_mm=34304.0) as sim:
        with open_stage(sim.port, "apt", counts_per_mm=34304.0, **FAST) as z:
            z.home(timeout=5)
            target = float(rng.uniform(1, 20))
            z.move_to(target, timeout=5)
            assert abs(sim.position_mm - target) <= 1 / 34304.0


def test_stale_bytes_at_open_are_purged_or_skipped():
    junk = b"\x91\x04\x0E\x00\x81\x50" + bytes(range(40))   # a truncated status and noise
    with AptSimulator(speedup=400.0, stale_bytes=junk) as sim:
        with open_stage(sim.port, "apt", **FAST) as z:
            assert z.info.serial == sim.serial_number
            z.home(timeout=5)
            assert z.position() == 0.0


def test_garbled_and_dropped_replies_are_asked_again(sim):
    sim.garble["HW_GET_INFO"] = 1
    with open_stage(sim.port, "apt", **FAST) as z:
        assert z.info.serial == sim.serial_number
        assert names(sim).count("HW_REQ_INFO") == 2
        assert z._decoder.discarded > 0
        sim.drop["MOT_GET_DCSTATUSUPDATE"] = 1
        z.position()
        sim.drop["MOT_GET_DCSTATUSUPDATE"] = 10**6
        with pytest.raises(StageTimeoutError, match="MOT_GET_DCSTATUSUPDATE"):
            z.position()
        sim.drop.clear()


def test_lost_move_completed_still_finishes(sim):
    with open_stage(sim.port, "apt", **FAST) as z:
        z.home(timeout=5)
        sim.drop["MOT_MOVE_COMPLETED"] = 1
        z.move_to(3.0, timeout=5)
        assert abs(z.position() - 3.0) < 1e-4


def test_homing_that_never_finishes_times_out_and_stops(sim):
    sim.homing_never_finishes = True
    with open_stage(sim.port, "apt", **FAST) as z:
        t = time.monotonic()
        with pytest.raises(HomingTimeoutError, match="homing"):
            z.home(timeout=0.3)
        assert time.monotonic() - t < 2.0
        assert "MOT_MOVE_STOP" in names(sim)
        assert sim.mode == "idle"


def test_limit_hit_raises_and_stops(sim):
    with open_stage(sim.port, "apt", **FAST) as z:
        z.home(timeout=5)
        sim.limit_switch = (-1.0, 7.5)
        with pytest.raises(StageLimitError, match="forward limit"):
            z.move_to(10.0, timeout=5)
        assert "MOT_MOVE_STOP" in names(sim)
        assert abs(sim.position_mm - 7.5) < 1e-9 and sim.mode == "idle"


def test_keepalive_at_least_once_a_second_while_moving():
    # a real-time move of about 1.4 s: 5 mm at 2.4 mm/s, simulated clock 1.5x wall clock
    with AptSimulator(speedup=1.5, start_mm=0.0) as sim:
        with open_stage(sim.port, "apt", require_homed=False, **FAST) as z:
            t0 = time.monotonic()
            z.move_to(5.0, timeout=10)
            t1 = time.monotonic()
    assert t1 - t0 > 1.2
    acks = [t for t in sim.acks if t0 <= t <= t1]
    gaps = np.diff([t0] + acks + [t1])
    assert len(acks) >= 2 and gaps.max() < 1.0


def test_refusals_before_anything_is_sent(sim):
    with open_stage(sim.port, "apt", **FAST) as z:
        time.sleep(0.05)
        sent = len(sim.received)
        with pytest.raises(ValueError, match="position_mm=30"):
            z.move_to(30.0)
        with pytest.raises(TypeError, match="position_mm"):
            z.move_to("3 mm")
        time.sleep(0.05)
        assert len(sim.received) == sent
        with pytest.raises(StageNotReferencedError, match="home"):
            z.move_to(3.0)
    with pytest.raises(ValueError, match="kind"):
        open_stage(sim.port, "pi")
    with pytest.raises(ValueError, match="counts_per_mm"):
        open_stage(sim.port, "apt", counts_per_mm=-1)
