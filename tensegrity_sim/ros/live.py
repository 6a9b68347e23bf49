"""The live node's loop, whatever carries its messages (DDS: :mod:`.dds_node`; Foxglove:
:mod:`.foxglove_node`). A transport is the logic's raw output callback with a ``poll(logic, log)`` that hands
the logic whatever inputs arrived, and a ``wait(timeout)`` that blocks until an input may have arrived or
``timeout`` s pass (True: one may have; False: the time is up)."""
from __future__ import annotations

import contextlib
import gc
import logging
import os
from typing import Callable

from .log import LogRecorder, SignalLatch
from .node_logic import SimNodeLogic

__all__ = ["DIAGNOSTICS_PERIOD", "DIAGNOSTICS_WAIT", "SPARE_FOR_IDLE", "StepperScheduling", "idle_work", "run_logged",
           "spin", "take_between_ticks"]

DIAGNOSTICS_PERIOD = 1.0  # s of wall-clock time between two /diagnostics, as the rclpy node
DIAGNOSTICS_WAIT = 0.1    # s that due /diagnostics wait for idle time at most
SPARE_FOR_IDLE = 0.5      # tick periods left before the next tick in which spin does its idle work


class StepperScheduling:
    """The stepping thread's Linux scheduling policy (parameter ``thread_priority``): ``SCHED_FIFO`` at that
    priority while the node runs on a schedule, the default policy otherwise (as fast as possible, the loop
    never sleeps and would keep every ordinary thread off its core). A FIFO thread runs before every ordinary
    one and without timer slack, so a tick is no longer late because another process or the hypervisor's
    other work held the core: on this project's 2-core VM (``bench/bench_wakeups.py``) a thread sleeping to a
    1 ms grid woke over a period late 18 and 31 times in 20,000 on the default policy, 9 and 4 on FIFO 50. Threads that exist
    already (the transport's) keep their policy. Refused (no root, CAP_SYS_NICE or rtprio limit), the node
    warns once and steps on the default policy."""

    def __init__(self, priority: int, log: logging.Logger):
        self._priority = priority
        self._log = log
        self._fifo = False
        self._refused = priority == 0

    def follow(self, scheduled: bool) -> None:
        """FIFO if ``scheduled`` (the node steps on a real-time schedule), the default policy if not."""
        if self._refused or scheduled == self._fifo:
            return
        policy, priority = (os.SCHED_FIFO, self._priority) if scheduled else (os.SCHED_OTHER, 0)
        try:
            os.sched_setscheduler(0, policy, os.sched_param(priority))   # 0: the calling thread
        except OSError as exc:
            self._refused = True
            self._log.warning(f"thread_priority {self._priority}: the OS refused SCHED_FIFO ({exc.strerror or exc}); "
                              f"stepping on the default scheduler (root, CAP_SYS_NICE or an rtprio limit of at least "
                              f"{self._priority}, e.g. ulimit -r {self._priority}, grants it)")
            return
        self._fifo = scheduled

    def restore(self) -> None:
        """The default policy again (the thread as the node found it)."""
        self.follow(False)


def run_logged(logic: SimNodeLogic, transport, path, *, latch: SignalLatch, log: logging.Logger, serving: str,
               notes: tuple[str, ...] = (), extra: Callable[[], list[str]] = list) -> None:
    """Log to ``path`` (none if empty), say ``serving`` and each of ``notes``, :func:`spin` until SIGINT or
    SIGTERM, then print the summary, ``extra()`` lines and the log files; the log is finished however it
    ends."""
    recorder = LogRecorder(path, logic.channels(), logic.run_info()) if path else None
    logic.recorder = recorder
    try:
        with recorder or contextlib.nullcontext():
            log.info(serving + (f"; logging to {path}" if path else ""))
            for note in notes:
                log.info(note)
            spin(logic, transport, latch=latch, log=log)
    finally:
        lines = logic.summary() + extra() + [f"{'log':<27} {p}" for p in (recorder.paths if recorder else [])]
        print("\n".join(lines), flush=True)


def idle_work(logic: SimNodeLogic, left: Callable[[], float], period: float, diagnostics_due: bool,
              diagnostics_overdue: bool) -> bool:
    """The loop's work after a tick that no step waits for, each piece while ``left()`` (s to the next tick)
    is more than :data:`SPARE_FOR_IDLE` of a tick ``period``: the waiting markers and contact events, the steps
    ahead, ``/diagnostics`` if due (at once if overdue), the log's write-out. Whether it published
    ``/diagnostics``. (:func:`spin`'s; ``bench/bench_node.py --in-process`` turns the node by it too.)"""
    spare = SPARE_FOR_IDLE * period
    if left() > spare:
        logic.send_waiting()
    if left() > spare:
        logic.look_ahead()
    published = diagnostics_overdue or (diagnostics_due and left() > spare)
    if published:
        logic.publish_diagnostics()
    if logic.recorder is not None and left() > spare:
        logic.recorder.drain()
    return published


def take_between_ticks(logic: SimNodeLogic, take: Callable[[], None], left: Callable[[], float], period: float) -> None:
    """An input that came between two ticks: taken now (``take()``), and the step after it computed ahead if
    ``left()`` (s to the next tick) is more than :data:`SPARE_FOR_IDLE` of a tick ``period``, so that the tick
    only hands that step out rather than decoding, rewinding the steps ahead and stepping. (:func:`spin`'s;
    ``bench/bench_node.py --in-process`` takes the controller's answers by it too.)"""
    take()
    if left() > SPARE_FOR_IDLE * period:
        logic.look_ahead()


def spin(logic: SimNodeLogic, transport, *, latch: SignalLatch, log: logging.Logger) -> None:
    """The node's single thread, as the rclpy node's executor: every ``1/step_rate`` s of wall-clock time
    take the inputs, run the steps due (:meth:`SimNodeLogic.tick`), and once a second publish
    ``/diagnostics``; until SIGINT or SIGTERM, which ``latch`` raises here, between two ticks. The node is
    warmed up first (:meth:`SimNodeLogic.warm_up`), so its schedule starts with nothing left to compile.
    Between ticks the loop waits on the transport rather than sleeping: an input that comes then is taken at
    once, and the step after it computed ahead (:func:`take_between_ticks`; what a tick that took it paid
    before: 0.45-0.8 ms of CPU time at p99.9 to receive it in 60 s ``bench/bench_node.py`` runs timed phase by
    phase, a one-off, and the step it rewound). It acts on the same step either way: the simulation runs as if
    the tick had taken it.

    Ticks wake on the logic's schedule (:meth:`SimNodeLogic.next_tick`, on its clock), not on a cadence of
    their own: a cadence restarted after a long tick sits at a random phase of the schedule, and then a
    wake-up a fraction of a period late owes two steps (measured in 60 s of ``bench/bench_node.py``: 2,133
    such catch-up ticks against 281 overruns).

    Work that no step waits for is done in the loop's idle time, each piece while more than
    :data:`SPARE_FOR_IDLE` of a tick period is left before the next tick, rather than inside a tick: a
    publication's markers and contact events (:attr:`SimNodeLogic.idle_outputs`: in a 30 s
    ``bench/bench_node.py`` run timed tick by tick, the ticks that drew markers took 0.52 ms at the median
    against 0.15 ms for the other publications, and made most of the slowest 0.1 %), the steps up to the next
    publication (:meth:`SimNodeLogic.look_ahead`: in 30 s runs timed phase by phase, ticks that took over 0.3 ms
    of CPU time went from 3,185-3,354 to 925), ``/diagnostics`` (0.4 ms at the median, up to 1.1 ms; due ones
    wait :data:`DIAGNOSTICS_WAIT` at most), and the log's waiting messages and its periodic write-out
    (:meth:`.log.LogRecorder.drain`). Whatever must follow them (the next publication) sends them first, so a
    loop without idle time still sends everything, in order. The stepping thread runs on ``SCHED_FIFO`` if
    ``thread_priority`` asks for it (:class:`StepperScheduling`); how late each wake-up comes goes to the
    statistics (:meth:`SimNodeLogic.woke`), so that a tick of two steps after a wake-up over a period late is
    told from one after a long tick."""
    clock = logic.clock
    logic.warm_up()
    # what exists now (the package, numba's kernels, the transport: ~150,000 objects) is kept out of the
    # collector's full passes, which took ~55 ms over them (a tick): in 60 s bench_node runs the worst tick was
    # 11.6 ms and 536 ms with this, 77 ms and 90 ms without; the 536 ms was numba compiling its typed lists'
    # methods at the first member contact (now the detection kernels return arrays)
    gc.collect()
    gc.freeze()
    scheduling = StepperScheduling(logic.settings.thread_priority, log)
    logic.restart_schedule()   # after the collection (tens of ms), which the schedule does not owe
    logic.idle_outputs = True
    try:
        next_tick = clock()
        next_diagnostics = next_tick + DIAGNOSTICS_PERIOD
        while True:
            latch.raise_if_signalled()
            scheduling.follow(logic.settings.real_time_factor > 0.0)
            transport.poll(logic, log)
            logic.tick()
            # the logic's own schedule decides how many steps each tick runs, so a late tick is caught up in
            # steps, not in extra ticks; paused, or with no schedule, ticks keep an absolute cadence
            now = clock()
            on_schedule = logic.next_tick(now)
            period = 1.0 / logic.settings.step_rate
            next_tick = next_tick + period if on_schedule is None else on_schedule
            due = now >= next_diagnostics
            overdue = due and now >= next_diagnostics + DIAGNOSTICS_WAIT
            if idle_work(logic, lambda: next_tick - clock(), period, due, overdue):
                next_diagnostics = clock() + DIAGNOSTICS_PERIOD
            delay = next_tick - clock()
            while delay > 0:
                arrived = transport.wait(delay)
                late = clock() - next_tick
                if not arrived or late >= 0.0:   # the tick's time came (an input then is the tick's to take)
                    logic.woke(late)
                    break
                take_between_ticks(logic, lambda: transport.poll(logic, log), lambda: next_tick - clock(), period)
                delay = next_tick - clock()
            else:   # the idle work, or an input, ran past the tick's time
                next_tick = clock()
    except BaseException:
        # the last publication whole in the log (SIGINT, SIGTERM), or as much of it as a failing transport or log
        # still takes: the error that ended the loop is the one raised
        with contextlib.suppress(Exception):
            logic.send_waiting()
        raise
    finally:
        logic.idle_outputs = False
        scheduling.restore()
        gc.unfreeze()   # the process as the node found it
