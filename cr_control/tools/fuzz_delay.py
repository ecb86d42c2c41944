"""cr_fuzz's ``delay`` suite: the Panda with a wrist sensor (``panda_ft``) behind a slow
driver. Each case runs the session's plant with a transport delay or late bursts
(:mod:`cr_sim.transport_delay`; the plant node's ``command_delay_cycles`` and
``late_burst_*``, set as cr_session's ``-p plant.<name>=<value>``) and sends nothing: the
controller is not told (it keeps the profile's 1 cycle). Judged, besides alive, finite,
no safe stop and resumed: no joint above half its URDF velocity limit, and the true
contact force within the suite's baseline's margin (FORCE_MARGIN x + FORCE_FLOOR).

A late burst: the driver keeps applying the command it applied last for 20-70 cycles, then
catches up. The burst draws are seeded, so every run has the same bursts at the same plant
steps (:func:`burst_draws` counts them); BURSTS_SEED's begin 3.6 s and 5.3 s into the plant's
run at ~1 %, and from 2.8 s on at ~5 %: after the tool has settled on the table.
"""

from __future__ import annotations

import numpy as np

from cr_control.experiments.wiping import late_bursts
from cr_control.robots import ROBOTS
from cr_control.tools.fuzz_case import Case, Suite, nothing, plant_args

SUITES = {"delay": Suite("delay_baseline", "panda_ft")}
#: The delay cases' joints stay below this share of their URDF velocity limits.
SPEED_LIMIT_SHARE = 0.5
#: The driver's constant delay of the delay cases (cycles; the profile's is 1).
DELAY_CYCLES = 3
#: The bursts' shares of late cycles (20-70 cycles each at 1 kHz:
#: :func:`cr_control.experiments.wiping.late_bursts`, as the wiping study draws them).
BURSTS_1PCT = 0.01
BURSTS_5PCT = 0.05
#: The bursts' seed: at 1 %, bursts at plant steps 3635 and 5257 (90 cycles late in 10 s);
#: at 5 %, 11 bursts from step 2821 on (482 cycles late in 10 s).
BURSTS_SEED = 2


def bursts(fraction: float) -> dict[str, object]:
    """The plant's late-burst parameters for about ``fraction`` of the cycles late."""
    return dict(late_bursts(SUITES["delay"].robot, fraction, BURSTS_SEED))


def burst_draws(fraction: float, cycles: int) -> tuple[int, int]:
    """(bursts started, cycles late) in the first ``cycles`` plant steps: the plant's own
    draws (:class:`cr_sim.transport_delay.TransportDelay` with the same parameters)."""
    from cr_sim.transport_delay import TransportDelay

    p = bursts(fraction)
    delay = TransportDelay(0, p["late_burst_probability"],
                           (p["late_burst_min_cycles"], p["late_burst_max_cycles"]),
                           p["late_burst_seed"])
    command = np.zeros(1)
    for _ in range(cycles):
        delay(command)
    return delay.bursts, delay.late_cycles


def note_bursts(fraction: float):
    """A send that notes the bursts the session's plant draws over its run."""
    def send(intruder) -> None:
        session = intruder.session
        cycles = round(session.cfg.duration * ROBOTS[intruder.robot or "panda_ft"].rate_hz)
        started, late = burst_draws(fraction, cycles)
        intruder.notes.append(f"the plant's draws: {started} burst(s), {late} of {cycles} "
                              f"cycles late ({100.0 * late / cycles:.1f} %)")
    return send


def _delay_case(name: str, what: str, send=nothing, **plant: object) -> Case:
    return Case(name, what, send, suite="delay", session_args=plant_args(**plant),
                speed_judged=False, force_judged=True, speed_limit_share=SPEED_LIMIT_SHARE)


CASES = [
    Case("delay_baseline", "nothing (the run the delay cases are judged against)",
         nothing, suite="delay"),
    _delay_case("delay_3_cycles", f"the driver applies every command {DELAY_CYCLES} cycles late "
                "(plant command_delay_cycles; the profile's 1)", command_delay_cycles=DELAY_CYCLES),
    _delay_case("late_bursts_1pct", "late bursts of 20-70 cycles, ~1 % of the cycles late",
                note_bursts(BURSTS_1PCT),
                **bursts(BURSTS_1PCT)),
    _delay_case("late_bursts_5pct", "late bursts of 20-70 cycles, ~5 % of the cycles late",
                note_bursts(BURSTS_5PCT),
                **bursts(BURSTS_5PCT)),
    _delay_case("delay_3_late_bursts_1pct", f"{DELAY_CYCLES} cycles of delay and late bursts, "
                "~1 % of the cycles late", note_bursts(BURSTS_1PCT),
                command_delay_cycles=DELAY_CYCLES, **bursts(BURSTS_1PCT)),
]
