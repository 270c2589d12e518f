"""factory.verify.VerifyAhead: op 1's verify begun in rounds while later operations are planned gives the verdict
and stock verify from the first move gives, also when the rapid check then changes an operation (issue 35)."""

from __future__ import annotations

import dataclasses
import time
from unittest import mock

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import cadcam.stock as stock
import factory.verify
from cadcam.model import Job, Motion
from cadcam.post import FitAhead, PostOptions, post_process
from cadcam.rest import from_and_to_safe_height
from cadcam.verify import VerifyOptions
from factory.verify import VerifyAhead, run_verify
from tests.cadcam.test_post import BALL, CUT, FLAT, SETUP, SLOW, _pocket_op, _raster_op
from tests.cadcam.test_verify import box

POST = PostOptions()
OPTIONS = VerifyOptions(cell=0.5)
#: The part: a block under the cuts, so verify holds every move against it.
PART = box([2, 2, -20], [78, 58, -6])


def _operations():
    """Four operations, two tools: a pocket, a raster with the ball, the pocket again (cutting little), a raster
    with the flat end mill."""
    pocket = _pocket_op()
    again = dataclasses.replace(pocket, name="pocket again", points=pocket.points + [0.5, 0.5, 0.0])
    return [pocket, _raster_op(BALL, SLOW, "raster ball"), again, _raster_op(FLAT, CUT, "raster flat")]


def _verified(job: Job, resume=None):
    program = post_process(job, POST)
    batches = [0]
    real = stock._run_batch

    def counting(*args, **kwargs):
        batches[0] += 1
        return real(*args, **kwargs)

    with mock.patch.object(stock, "_run_batch", counting):
        result = run_verify(program.text, "p.nc", job.setup, {t.number: t for t in job.tools}, np.asarray(PART),
                            OPTIONS, resume=resume)
    return result, batches[0]


def _same(a, b) -> None:
    assert a.report.to_dict() == b.report.to_dict()
    for name in ("stock_top", "part_top", "removed_volume"):
        x, y = getattr(a.simulation, name), getattr(b.simulation, name)
        assert np.array_equal(x, y), name  # to the bit


def _ahead(ops, rounds):
    """A VerifyAhead told of ``ops`` as a planner plans them: after each of ``rounds`` operations, each
    round waited for (as a processor idle meanwhile would finish it), then all of them."""
    ahead = VerifyAhead(FitAhead(POST), POST, OPTIONS, np.asarray(PART))
    assert ahead.enabled
    for k in rounds:
        ahead.offer(ops[:k], SETUP)
        ahead.state([from_and_to_safe_height(op, SETUP.safe_z) for op in ops])  # waits for the round
    ahead.offer_all(ops, SETUP)
    return ahead


@pytest.fixture
def two_processors(monkeypatch):
    monkeypatch.setenv("FACTORY_THREADS", "2")
    # a processor idle, whatever else the machine runs meanwhile (the suite's other workers)
    monkeypatch.setattr(factory.verify.IdleMeter, "idle", lambda self, own=0.0: 2.0)
    monkeypatch.setattr(factory.verify, "OVERTAKE_BELOW", 0.0)  # each round waited for, however slowly it runs
    with mock.patch.object(stock, "_PAIR_BUDGET", 4000):  # many batches, in the forked rounds too
        yield


def test_verify_resumed_from_rounds_ahead_is_verify_from_the_first_move(two_processors):
    ops = _operations()
    ahead = _ahead(ops, rounds=(1, 2, 3))
    job = Job("p", SETUP, tuple(from_and_to_safe_height(op, SETUP.safe_z) for op in ops))
    state = ahead.state(job.operations)
    assert state is not None and len(state.bounds) > 2
    plain, n_plain = _verified(job)
    resumed, n_resumed = _verified(job, state)
    _same(resumed, plain)
    assert n_resumed == n_plain - (len(state.bounds) - 1)  # the batches cut ahead were not cut again
    # the rounds' fits are the post's: posting with them is posting without
    assert post_process(job, POST, ahead=ahead.fits).text == post_process(job, POST).text


@settings(max_examples=6, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(changed=st.integers(0, 3), how=st.sampled_from(["slowed", "moved"]),
       rounds=st.sampled_from([(1, 2, 3), (2,), (3,)]))
def test_a_round_invalidated_by_a_changed_operation_gives_the_plain_verdict(two_processors, changed, how, rounds):
    """The speculation invalidated: after the rounds, the rapid check changes one operation (a rapid slowed to
    the plunge feed, or a point moved): verify resumes only from a state of the operations before it, and its
    verdict and stock are those of verify from the first move."""
    ops = _operations()
    ahead = _ahead(ops, rounds)
    final = [from_and_to_safe_height(op, SETUP.safe_z) for op in ops]
    op = final[changed]
    rapid = np.flatnonzero(op.motion == Motion.RAPID)
    if how == "slowed":
        motion = op.motion.copy()
        motion[rapid[-1]] = Motion.PLUNGE
        final[changed] = dataclasses.replace(op, motion=motion)
    else:
        points = op.points.copy()
        points[len(points) // 2, 2] -= 0.25
        final[changed] = dataclasses.replace(op, points=points)
    job = Job("p", SETUP, tuple(final))
    state = ahead.state(job.operations)
    if changed == 0:  # nothing the job holds as it was cut ahead
        assert state is None
    plain, n_plain = _verified(job)
    resumed, _ = _verified(job, state)
    _same(resumed, plain)


def test_with_one_processor_nothing_is_begun_ahead(monkeypatch):
    monkeypatch.setenv("FACTORY_THREADS", "1")
    ops = _operations()
    ahead = VerifyAhead(FitAhead(POST), POST, OPTIONS, np.asarray(PART))
    assert not ahead.enabled
    ahead.offer(ops[:2], SETUP)
    assert ahead.state([from_and_to_safe_height(op, SETUP.safe_z) for op in ops]) is None


def test_on_a_busy_machine_no_round_is_begun_and_verify_is_the_plain_one(monkeypatch):
    """Two processors, both kept busy by other work (a suite's workers, a workflow's jobs): no round starts, as
    it would hardly advance at its lower priority and verify would wait for it; the operations are fitted as
    without verify ahead, and verify cuts from the first move."""
    monkeypatch.setenv("FACTORY_THREADS", "2")
    monkeypatch.setattr(factory.verify.IdleMeter, "idle", lambda self, own=0.0: 0.4)
    ops = _operations()
    ahead = VerifyAhead(FitAhead(POST), POST, OPTIONS, np.asarray(PART))
    for k in (1, 2, 3):
        ahead.offer(ops[:k], SETUP)
        assert ahead._round is None
    ahead.offer_all(ops, SETUP)
    job = Job("p", SETUP, tuple(from_and_to_safe_height(op, SETUP.safe_z) for op in ops))
    assert ahead.state(job.operations) is None
    assert post_process(job, POST, ahead=ahead.fits).text == post_process(job, POST).text


def test_a_round_begins_where_the_machine_left_a_processor_idle_its_own_time_counted_idle(monkeypatch):
    """The gate reads the machine's idle processors since its last look (cadcam.parallel.IdleMeter), the rounds'
    own processor time counted idle: on a quiet two-processor machine a round keeps the second one, and the
    next round is judged with it."""
    monkeypatch.setenv("FACTORY_THREADS", "2")
    looks = []

    def idle(self, own=0.0):
        looks.append(own)
        return 0.2 + own  # what is idle besides the rounds: too little alone

    monkeypatch.setattr(factory.verify.IdleMeter, "idle", idle)
    monkeypatch.setattr(factory.verify, "OVERTAKE_BELOW", 0.0)  # the round waited for, however slowly it runs
    ops = _operations()
    ahead = VerifyAhead(FitAhead(POST), POST, OPTIONS, np.asarray(PART))
    ahead._spent = 1.0  # as if a round had just taken a processor for a second
    ahead.offer(ops[:1], SETUP)
    assert ahead._round is not None and looks == [1.0]
    ahead.state([from_and_to_safe_height(op, SETUP.safe_z) for op in ops])  # waits for the round
    ahead.offer(ops[:2], SETUP)
    assert looks[1] > 0.0  # the first round's processor time
    assert (ahead._round is not None) == (looks[1] >= factory.verify.AHEAD_IDLE - 0.2)
    ahead.cancel()
    monkeypatch.setattr(factory.verify.IdleMeter, "idle", lambda self, own=0.0: None)  # too soon to tell
    again = VerifyAhead(FitAhead(POST), POST, OPTIONS, np.asarray(PART))
    again.offer(ops[:1], SETUP)
    assert again._round is None


def _crawling(*args):
    """A round that gets next to no processor (the machine's other work took it back): it waits, then cuts."""
    time.sleep(60.0)
    return factory.verify._verify_round(*args)


def test_verify_overtakes_a_round_that_crawls(two_processors, monkeypatch):
    """The race forced: the last round runs on next to no processor (it sleeps). Verify does not wait for it: the
    round is ended within a look or two, verify resumes from the round before (its operations fitted by the
    post itself), and its verdict and stock are verify's from the first move. Rounds that run are waited for."""
    ops = _operations()
    ahead = _ahead(ops[:2], rounds=(1, 2))  # two rounds waited for (the fixture's): cut up to op 2
    assert [n for n, _ in ahead._states] == [1, 2]
    monkeypatch.setattr(factory.verify, "OVERTAKE_BELOW", factory.verify.AHEAD_IDLE)
    monkeypatch.setattr(factory.verify, "_verify_round", _crawling)
    ahead.offer_all(ops, SETUP)
    assert ahead._round is not None
    job = Job("p", SETUP, tuple(from_and_to_safe_height(op, SETUP.safe_z) for op in ops))
    began = time.monotonic()
    state = ahead.state(job.operations)
    assert time.monotonic() - began < 10.0  # not the crawling round's minute
    assert ahead._round is None and state is not None
    assert state.moves < len(_verified(job)[0].simulation.removed_volume) - 1  # the last two operations not cut
    plain, n_plain = _verified(job)
    resumed, n_resumed = _verified(job, state)
    _same(resumed, plain)
    assert n_resumed < n_plain
    assert post_process(job, POST, ahead=ahead.fits).text == post_process(job, POST).text


def test_the_last_round_posts_and_parses_the_whole_program_as_the_post_and_verify_would(two_processors):
    """The round begun as the rapid check starts (every operation planned) posts the job as it will be posted and
    parses all of it: the post and verify take both, the same text and moves to the bit, only for that job (its
    operations unchanged, its name and source, no parameter the post reads)."""
    from cadcam.gcode import parse_gcode

    ops = _operations()
    final = tuple(from_and_to_safe_height(op, SETUP.safe_z) for op in ops)
    ahead = VerifyAhead(FitAhead(POST), POST, OPTIONS, np.asarray(PART), "p", "ab12")
    ahead.offer(ops[:2], SETUP)
    ahead.state(final)
    ahead.offer_all(ops, SETUP)
    job = Job("p", SETUP, final, source_sha256="ab12")
    state = ahead.state(job.operations)
    posted = ahead.posted(job)
    assert posted is not None and state is not None
    program, moves = posted
    assert program.text == post_process(job, POST).text
    plain = parse_gcode(program.text, source="p.nc")
    for name in ("points", "motion", "tool", "feed", "line"):
        assert getattr(moves, name).tobytes() == getattr(plain, name).tobytes(), name
    verified = run_verify(program.text, "p.nc", SETUP, {t.number: t for t in job.tools}, np.asarray(PART), OPTIONS,
                          resume=state, moves=moves)
    _same(verified, _verified(job)[0])
    # another job's: posted and parsed again
    assert ahead.posted(dataclasses.replace(job, part_name="q")) is None
    assert ahead.posted(dataclasses.replace(job, source_sha256="cd34")) is None
    assert ahead.posted(dataclasses.replace(job, parameters={"setup_note": "turned over"})) is None
    moved = final[3].points.copy()
    moved[5, 2] -= 0.25
    assert ahead.posted(dataclasses.replace(job, operations=(*final[:3], dataclasses.replace(final[3], points=moved)))) is None
    slower = dataclasses.replace(final[1], feeds=None if final[1].feeds is None else final[1].feeds * 0.5,
                                 name=final[1].name + " slower")
    assert ahead.posted(dataclasses.replace(job, operations=(final[0], slower, *final[2:]))) is None


def test_every_job_parameter_the_post_reads_is_one_a_round_refuses_to_reuse_its_program_for():
    """A round's program is reused only for a job without the parameters the post writes into the text
    (``POSTED_PARAMETERS``): a parameter the post came to read and the list did not name would let verify pass a
    program posted without it. Read from the post's source, so adding such a read without naming it fails here."""
    import inspect
    import re

    import cadcam.post
    from cadcam.post import POSTED_PARAMETERS

    source = inspect.getsource(cadcam.post)
    read = set(re.findall(r"parameters(?:\.get\(|\[)\s*[\"'](\w+)[\"']", source))
    assert read, "the post reads no job parameter: the scan no longer sees how it reads them"
    assert read <= set(POSTED_PARAMETERS), sorted(read - set(POSTED_PARAMETERS))
