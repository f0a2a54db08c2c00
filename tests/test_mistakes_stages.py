"""The stage drivers under a user's mistakes and a controller's silences (the fourth audit).

1. APT: a motion's end (``MOVE_COMPLETED``, ``MOVE_HOMED``) left unread by a ``wait=False``
   move, a poll of ``is_moving()`` or a wait that ended by status was taken for the next
   motion's end: ``move_to`` returned at once while the stage still moved.
2. A controller that stops answering mid-motion was left moving: CONEX ``_wait_state``, both
   drivers' ``wait_until_stopped()`` and ``close()`` raised (or closed) without sending a stop.
3. APT ``move_by`` before homing was accepted (moved relative to an unreferenced count).
4. A stage used after ``close()`` raised pyserial's bare ``PortNotOpenError``; ``with`` on a
   closed stage was accepted.

Nothing here can hang: every wait has the driver's own short timeout, the simulators run fast
(or slow, where a motion must outlast a check, with the check's timeout far shorter than the
motion).
"""

import time

import pytest

from clholo.tools.stages import (StageError, StageNotReferencedError, StageTimeoutError,
                                 open_stage)
from clholo.tools.stages.base import StageClosedError
from clholo.tools.stages.simulators import AptSimulator, ConexSimulator

APT_FAST = dict(reply_timeout=0.2, poll=0.01, purge_dwell=0.005)
CONEX_FAST = dict(reply_timeout=0.2, poll=0.005, reset_wait=0.03)
FAST = {"apt": APT_FAST, "conex": CONEX_FAST}
#: a fault count that does not run out during a test
ALWAYS = 10**9
#: the replies a controller that stopped answering no longer sends
SILENT = {"apt": {"MOT_GET_DCSTATUSUPDATE": ALWAYS, "MOT_MOVE_COMPLETED": ALWAYS,
                  "MOT_MOVE_STOPPED": ALWAYS, "MOT_MOVE_HOMED": ALWAYS},
          "conex": {"TS": ALWAYS, "TE": ALWAYS, "TP": ALWAYS, "TB": ALWAYS}}
STOP = {"apt": "MOT_MOVE_STOP", "conex": "1ST"}


def names(sim):
    return [n for _, n in sim.received]


def until(predicate, timeout=1.0):
    """Wait for the simulator's thread to catch up (it runs behind ours); True when it did."""
    deadline = time.monotonic() + timeout
    while not predicate():
        if time.monotonic() >= deadline:
            return False
        time.sleep(0.005)
    return True


def simulator(kind, **kwargs):
    if kind == "apt":
        return AptSimulator(**kwargs)
    return ConexSimulator(reset_s=4.0, **kwargs)


def moving(sim):
    return sim.mode == "moving" if isinstance(sim, AptSimulator) else sim.state == "28"


# --- 1: a motion's end is taken only by the motion it belongs to -----------------------------

@pytest.mark.parametrize("settle", ["wait_until_stopped", "poll is_moving"])
@pytest.mark.parametrize("second", ["move_to", "move_by"])
def test_apt_move_after_a_wait_false_move_waits_for_its_own_end(settle, second):
    # speedup 20: 2 -> 20 mm takes 7.5 s simulated, 0.375 s of wall clock
    with AptSimulator(speedup=20.0) as sim, open_stage(sim.port, "apt", **APT_FAST) as z:
        z.home(timeout=5)
        z.move_to(2.0, wait=False)
        if settle == "wait_until_stopped":
            z.wait_until_stopped(timeout=5)
        else:
            deadline = time.monotonic() + 5
            while z.is_moving() and time.monotonic() < deadline:
                time.sleep(0.01)
        t = time.monotonic()
        if second == "move_to":
            z.move_to(20.0, timeout=5)
        else:
            z.move_by(18.0, timeout=5)
        took = time.monotonic() - t
        assert not z.is_moving() and abs(z.position() - 20.0) < 1e-3, (took, z.position())
        assert took > 0.2, took


def test_apt_home_after_a_home_that_ended_by_status_waits_for_its_own_end():
    with AptSimulator(speedup=20.0) as sim, open_stage(sim.port, "apt", **APT_FAST) as z:
        sim.late_s = 0.3
        sim.late["MOT_MOVE_HOMED"] = 1    # the first home ends by status; MOVE_HOMED comes after
        z.home(timeout=5)
        time.sleep(0.4)
        assert z.position() == 0.0        # the late MOVE_HOMED has been read by now
        z.move_to(20.0, timeout=5)
        t = time.monotonic()
        z.home(timeout=5)                 # 20 mm back: 0.42 s of wall clock
        took = time.monotonic() - t
        assert sim.mode == "idle" and sim.homed and z.position() == 0.0, (took, sim.mode)
        assert took > 0.2, took


def test_apt_late_end_of_the_previous_move_is_not_taken_for_the_next():
    # the first move ends by status (its MOVE_COMPLETED is late); that completion arrives
    # while the second move runs, after the second move's command was sent
    with AptSimulator(speedup=10.0) as sim, open_stage(sim.port, "apt", **APT_FAST) as z:
        z.home(timeout=5)
        sim.late_s = 0.3
        sim.late["MOT_MOVE_COMPLETED"] = 1
        z.move_to(2.0, timeout=5)
        t = time.monotonic()
        z.move_to(20.0, timeout=5)        # 0.75 s of wall clock
        took = time.monotonic() - t
        assert not z.is_moving() and abs(z.position() - 20.0) < 1e-3, (took, z.position())
        assert took > 0.5, took


def test_apt_home_does_not_take_a_status_from_before_its_command():
    # a status reply that comes after its query was asked again is read only by the next wait:
    # this one says "homed, at 0 mm, not moving", which a home takes for its end
    with AptSimulator(speedup=40.0) as sim, open_stage(sim.port, "apt", **APT_FAST) as z:
        z.home(timeout=5)
        sim.late_s = 1.0
        sim.late["MOT_GET_DCSTATUSUPDATE"] = 1     # the move's first status query (at 0 mm)
        z.move_to(20.0, timeout=5)                 # 0.2 s of wall clock
        time.sleep(1.2)                            # the late reply is waiting in the port
        t = time.monotonic()
        z.home(timeout=5)                          # 20 mm back: 0.2 s
        took = time.monotonic() - t
        assert sim.mode == "idle" and sim.homed and z.position() == 0.0, (took, sim.mode)
        assert took > 0.1, took


def test_apt_home_waits_for_status_replies_still_on_their_way():
    # a slow bus: when the move's wait ends, the replies to its last status polls are still on
    # their way ("homed, not moving", from before the home); the home waits for them first
    with AptSimulator(speedup=40.0) as sim, open_stage(sim.port, "apt", **APT_FAST) as z:
        z.home(timeout=5)
        sim.latency_s = 0.03                       # three 10 ms polls in flight at any time
        z.move_to(20.0, timeout=5)
        t = time.monotonic()
        z.home(timeout=5)                          # 20 mm back: 0.2 s
        took = time.monotonic() - t
        assert sim.mode == "idle" and sim.homed and z.position() == 0.0, (took, sim.mode)
        assert took > 0.1, took


def test_apt_status_after_a_late_reply_is_the_current_one():
    # a status reply later than reply_timeout arrives after its query was answered by the
    # retry; unread, it answered the next query, whose own reply (asked before the move) then
    # answered is_moving(): "not moving" while the motor ran, and close() did not stop it
    with AptSimulator(speedup=400.0) as sim, open_stage(sim.port, "apt", **APT_FAST) as z:
        z.home(timeout=5)
        sim.speedup = 1.0                          # 0 -> 20 mm: 8 s
        sim.late_s = 0.3
        sim.late["MOT_GET_DCSTATUSUPDATE"] = 1
        assert z.position() == 0.0                 # answered by the retry
        time.sleep(0.4)                            # the late reply is waiting in the port
        z.move_to(20.0, wait=False)
        assert until(lambda: moving(sim))
        assert z.is_moving()
        z.close()
        assert until(lambda: not moving(sim)) and "MOT_MOVE_STOP" in names(sim)


def test_apt_query_does_not_take_a_late_reply_to_an_earlier_one():
    with AptSimulator(speedup=400.0) as sim, open_stage(sim.port, "apt", **APT_FAST) as z:
        z.home(timeout=5)
        sim.speedup = 1.0                          # 0 -> 20 mm: 8 s
        z.move_to(20.0, wait=False)
        sim.late_s = 0.3
        sim.late["MOT_GET_DCSTATUSUPDATE"] = 1
        assert z.is_moving()                       # answered by the retry
        z.stop()
        assert until(lambda: not moving(sim))
        time.sleep(0.4)                            # the late "moving" is waiting in the port
        assert not z.is_moving()


def test_conex_move_after_a_wait_false_move_waits_for_its_own_end():
    # the CONEX driver follows TS, asked after each command: the same sequence as the APT's
    with ConexSimulator(speedup=20.0, reset_s=4.0) as sim, \
            open_stage(sim.port, "conex", **CONEX_FAST) as c:
        c.home(timeout=5)
        c.move_to(-1.0, wait=False)
        c.wait_until_stopped(timeout=5)
        t = time.monotonic()
        c.move_to(3.0, timeout=5)          # 4 mm at 0.4 mm/s: 0.5 s of wall clock
        took = time.monotonic() - t
        assert not c.is_moving() and abs(c.position() - 3.0) < 1e-5, (took, c.position())
        assert took > 0.3, took


# --- 2: a controller that stops answering mid-motion is told to stop -------------------------

@pytest.fixture(params=["apt", "conex"])
def homed(request):
    """(kind, simulator, stage): homed fast, then the simulated clock slowed to the wall
    clock's, so a move lasts seconds (longer than any check below)."""
    kind = request.param
    sim = simulator(kind, speedup=400.0)
    stage = open_stage(sim.port, kind, **FAST[kind])
    try:
        stage.home(timeout=5)
        sim.speedup = 1.0
        yield kind, sim, stage
    finally:
        sim.drop = {}
        stage.close()
        sim.close()


def far(kind):
    return 20.0 if kind == "apt" else -10.0


def test_wait_until_stopped_stops_a_controller_that_stops_answering(homed):
    kind, sim, stage = homed
    stage.move_to(far(kind), wait=False)
    assert until(lambda: moving(sim))
    sim.drop = dict(SILENT[kind])
    t = time.monotonic()
    with pytest.raises(StageTimeoutError):
        stage.wait_until_stopped(timeout=1.0)
    assert time.monotonic() - t < 2.0
    assert until(lambda: not moving(sim)), names(sim)[-5:]
    assert STOP[kind] in names(sim)[-3:]


def test_close_stops_a_controller_that_stops_answering(homed):
    kind, sim, stage = homed
    stage.move_to(far(kind), wait=False)
    assert until(lambda: moving(sim))
    sim.drop = dict(SILENT[kind])
    t = time.monotonic()
    stage.close()                          # does not raise: it runs on the way out of faults
    assert time.monotonic() - t < 2.0 and stage.closed
    assert until(lambda: not moving(sim)), names(sim)[-5:]
    assert STOP[kind] in names(sim)[-3:]


@pytest.mark.parametrize("silent", ["TS", "TE"])
def test_conex_move_stops_when_the_controller_stops_answering(silent):
    # TS silent: the move's state polls fail (conex._wait_state); TE silent: the move's own
    # error query fails after PA was sent (conex._action)
    with ConexSimulator(speedup=400.0, reset_s=4.0) as sim, \
            open_stage(sim.port, "conex", **CONEX_FAST) as c:
        c.home(timeout=5)
        sim.speedup = 1.0                  # -10 mm at 0.4 mm/s: 25 s
        sim.drop = {silent: ALWAYS}
        t = time.monotonic()
        with pytest.raises(StageTimeoutError, match=f"1{silent}"):
            c.move_to(-10.0, timeout=2)
        assert time.monotonic() - t < 1.5
        assert until(lambda: sim.state != "28"), sim.state
        assert sim.state == "33" and "1ST" in names(sim)[-3:]
        sim.drop = {}


# --- 3: APT move_by before homing -----------------------------------------------------------

@pytest.mark.parametrize("kind", ["apt", "conex"])
def test_move_by_before_homing_is_refused(kind):
    with simulator(kind, speedup=400.0) as sim, open_stage(sim.port, kind, **FAST[kind]) as s:
        before = sim.position_mm
        with pytest.raises(StageNotReferencedError, match="home"):
            s.move_by(1.0, timeout=2)
        time.sleep(0.05)
        assert sim.position_mm == before and not moving(sim)
        assert "MOT_MOVE_RELATIVE" not in names(sim)


# --- 4: a closed stage says so ----------------------------------------------------------------

@pytest.mark.parametrize("kind", ["apt", "conex"])
def test_a_closed_stage_names_the_fix(kind):
    with simulator(kind, speedup=400.0) as sim:
        stage = open_stage(sim.port, kind, **FAST[kind])
        with stage:
            stage.home(timeout=5)
        assert stage.closed
        stage.close()                      # twice: harmless
        calls = {"move_to": lambda: stage.move_to(1.0, timeout=2),
                 "move_by": lambda: stage.move_by(0.5, timeout=2),
                 "position": stage.position, "is_moving": stage.is_moving,
                 "home": lambda: stage.home(timeout=2), "stop": stage.stop,
                 "wait_until_stopped": lambda: stage.wait_until_stopped(timeout=1),
                 "with": lambda: stage.__enter__()}
        for name, call in calls.items():
            with pytest.raises(StageClosedError) as err:
                call()
            assert str(err.value) == (f"the stage on {sim.port} is closed: open it again with "
                                      f"open_stage({sim.port!r}, kind={kind!r}, ...)"), name
            assert isinstance(err.value, StageError)
        with pytest.raises(StageClosedError):
            with stage:
                pass


# --- 5: a controller that stops answering while the user follows a wait=False move ----------

@pytest.mark.parametrize("query", ["position", "is_moving"])
def test_a_query_that_gets_no_reply_during_a_move_stops_the_motor(homed, query):
    """The user's own loop over ``position()`` (or ``is_moving()``) after ``move_to(...,
    wait=False)``: when the controller stops answering, the error says the stop was sent and
    the motor stops now, not at the ``with`` block's ``close()``."""
    kind, sim, stage = homed
    stage.move_to(far(kind), wait=False)
    assert until(lambda: moving(sim))
    sim.drop = dict(SILENT[kind])
    t = time.monotonic()
    with pytest.raises(StageTimeoutError, match="a motion was under way, so the stop command "
                                                "was sent"):
        getattr(stage, query)()
    assert time.monotonic() - t < 2.0
    assert until(lambda: not moving(sim)), names(sim)[-5:]
    assert STOP[kind] in names(sim)[-3:]


@pytest.mark.parametrize("end", ["waited", "polled"])
def test_a_query_that_gets_no_reply_at_rest_sends_no_stop(homed, end):
    """Once a status has shown the motor stopped (the move's own wait, or the user's polls of
    ``is_moving()`` after ``wait=False``), a lost reply is only a lost reply: the error says
    nothing of a motion and no stop command goes out."""
    kind, sim, stage = homed
    sim.speedup = 400.0
    target = 1.0 if kind == "apt" else -0.5
    if end == "waited":
        stage.move_to(target, timeout=5)
    else:
        stage.move_to(target, wait=False)
        deadline = time.monotonic() + 5
        while stage.is_moving() and time.monotonic() < deadline:
            time.sleep(0.01)
    assert not moving(sim)  # the simulator's state: no query of the driver's between
    sim.drop = dict(SILENT[kind])
    with pytest.raises(StageTimeoutError) as err:
        stage.position()
    assert "motion" not in str(err.value)
    time.sleep(0.05)
    assert STOP[kind] not in names(sim)[-6:]
