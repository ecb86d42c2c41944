"""The packed vectors the kernels read, named: the compiled views functions and the Python
side's Layouts are one definition (cr_control.core.packing.views_layout), and the vectors
are laid out as the kernels read them before their blocks were named.
"""

from collections import namedtuple

import numpy as np
import pytest
from numba import njit

from cr_control.core.packing import take, views_layout
from cr_control.core.topics import REFERENCE_FIELDS, STATUS_FIELDS
from cr_control.offline import run_scheme
from cr_control.schemes.blocks import backstepping as bs
from cr_control.schemes.blocks import contact_guard as guard
from cr_control.schemes.blocks import impedance_adaptation as impedance
from cr_control.schemes.blocks.references import (
    reference_gains,
    reference_gains_views,
    reference_state,
    reference_state_views,
)
from cr_control.schemes.blocks.sliding_impedance import sliding_gains
from cr_control.schemes.blocks.task_space import (
    NULL_SPACE_SIZE,
    common_blocks,
    common_gains_layout,
    law_blocks,
)
from cr_control.schemes.force import mrac_force as mrac
from cr_control.schemes.force.backstepping_force import RESULT, STATE, STATUS_EXTRA
from cr_control.schemes.impedance.nn_adaptive_impedance import NN_STATUS_FIELDS
from cr_control.schemes.impedance.sliding import _sizes as sliding_sizes
from cr_control.schemes.registry import make_controller

#: (m task axes, n joints): the thesis arms, a 3-axis 7-joint arm, a 1-axis line.
SHAPES = [(2, 2), (3, 7), (3, 6), (1, 1)]


def _same_blocks(views, layout, vector):
    """Every named view of ``vector`` is the Layout's block of the same name."""
    assert list(views._fields) == list(layout.shapes)
    for name, view in zip(views._fields, views, strict=True):
        assert np.array_equal(view, layout.view(vector, name)), name


@pytest.mark.parametrize(("m", "n"), SHAPES)
def test_reference_blocks_are_where_the_kernels_read_them(m, n):
    """The views the kernels take are the Layout's blocks, and both sit where the
    hand-written offsets had them (the guard's state at 3 m + n + 15, its gains at
    4 m + 8 + n; sizes 5 m + n + 16 + G_s and 4 m + 11 + n + G_g)."""
    gains_size, state_size = guard.guard_sizes(m)
    gains, state = reference_gains(m, n), reference_state(m, n)
    assert state.offset("guard") == 3 * m + n + 15
    assert state.offset("n_f") == 3 * m + n + 15 + state_size
    assert state.size == 5 * m + n + 16 + state_size
    assert gains.offset("guard") == 4 * m + 8 + n
    assert gains.offset("target_max_speed") == gains.size - 3
    assert gains.offset("reference_ramp_time") == gains.size - 1
    assert gains.size == 4 * m + 11 + n + gains_size
    vector = np.arange(float(state.size + 3))          # + 3: the scheme's own state after it
    views, end = reference_state_views(vector, m, n)
    assert end == state.size
    _same_blocks(views, state, vector)
    vector = np.arange(float(gains.size))
    views, end = reference_gains_views(vector, m, n)
    assert end == gains.size
    _same_blocks(views, gains, vector)
    assert views.guard.shape == (gains_size,)
    assert guard.guard_gains(m).size == gains_size


@pytest.mark.parametrize(("m", "n"), SHAPES)
def test_common_and_law_blocks(m, n):
    """common_blocks reads n and m from the task block and splits a packed gains vector as
    common_gains_layout says; the law's gains and state follow the common ones."""
    layout = common_gains_layout(n, m)
    assert [layout.offset(b) for b in ("limits", "order", "null_space", "reference")] == [
        10, 10 + 4 * n, 10 + 5 * n, 10 + 5 * n + NULL_SPACE_SIZE]
    gains = np.arange(float(layout.size + 4))
    gains[0], gains[1] = n, m
    views, law_at = common_blocks(gains)
    assert law_at == layout.size
    _same_blocks(views, layout, gains)
    state = np.arange(float(reference_state(m, n).size + 5))
    law_gains, law_state = law_blocks(gains, state)
    assert np.array_equal(law_gains, gains[layout.size:])
    assert np.array_equal(law_state, state[reference_state(m, n).size:])


_Gappy = namedtuple("_Gappy", ["a", "b"])


@njit
def _gappy_views(vector, m):
    a, k = take(vector, 0, m)
    b, k = take(vector, k + 1, m)        # one value skipped: not a Layout
    return _Gappy(a, b), k


@njit
def _short_views(vector, m):
    a, k = take(vector, 0, m)
    return _Gappy(a, vector[k:k]), k + 1    # says it ends one value after its blocks


def test_views_layout_refuses_what_is_no_layout():
    with pytest.raises(ValueError, match="block b starts at 4"):
        views_layout(_gappy_views, 3)
    with pytest.raises(ValueError, match="end at 2, it says 3"):
        views_layout(_short_views, 2)


@pytest.mark.parametrize("m", [1, 2, 3])
def test_sliding_blocks_are_the_layouts_sizes(m):
    """The sliding schemes' kernels split the law's gains and state with these sizes."""
    assert sliding_sizes(m) == (impedance.gains_layout(m).size, sliding_gains(m).size,
                                impedance.state_layout(m).size)


def test_backstepping_blocks_and_status_by_name():
    """The design's state and results (4.13-4.56) by name: sizes as the design has them,
    and a run's status reports the named blocks every cycle."""
    sizes = bs.Sizes(5, 2)
    assert RESULT.size == sizes.outputs
    assert STATE.size == bs.state_size(sizes) == 2 * sizes.n + 2 * sizes.p + 4
    assert (STATE.offset("theta_hat"), STATE.offset("rho_hat"), STATE.offset("u_prev")) == (
        10, 19, 21)
    assert (RESULT.offset("z"), RESULT.offset("gamma_2")) == (11, 13)
    run = run_scheme("backstepping_force", 0.2, {"f_d": 1.5})
    controller = make_controller("backstepping_force", {"f_d": 1.5})
    assert controller.status_fields[-len(STATUS_EXTRA):] == STATUS_EXTRA
    assert np.all(run.column("f_d_x") == 1.5)
    assert np.array_equal(run.column("tau_1"), run.command[:, 0])
    assert np.array_equal(run.column("r_x"), run.position[:, 0])
    assert np.array_equal(run.column("f_err_x"), 1.5 - run.force[:, 0])
    assert run.column("b3_hat")[0] == pytest.approx(0.65 * 20.0)      # theta_hat(0), printed
    assert run.column("d_hat")[0] == pytest.approx(0.65 * 0.05)
    assert np.ptp(run.column("z_1")) > 0.0 and np.ptp(run.column("a0_hat")) > 0.0
    # where force_cycle wrote them by number before: reference[6], status[10]
    assert REFERENCE_FIELDS.index("f_d_x") - 1 == 6 and STATUS_FIELDS.index("tau_1") - 1 == 10


#: Each scheme's own packed gains (its parameters but inv_variance = 1/rbf_variance), after
#: its family's.
OWN_GAINS = {
    "impedance": ["d_m", "k_m"],
    "fuzzy_unidirectional": ["lambda", "k_p", "k_n", "d_s", "d_med", "d_b", "f_max", "f_min"],
    "robust_adaptive_impedance": ["delta_M", "delta_C", "delta_G", "delta_f"],
    "nn_adaptive_impedance": ["d", "Gamma_M", "Gamma_C", "Gamma_G", "inv_variance"],
}


@pytest.mark.parametrize("scheme", sorted(OWN_GAINS))
def test_a_law_declares_itself_through_one_set_of_hooks(scheme):
    """A scheme extends its family's law_* hooks: its own gains are packed by name at the
    end of the law's block, where its kernel reads them, from its parameters; no other
    hooks (own_*, OWN) exist."""
    controller = make_controller(scheme)
    names = OWN_GAINS[scheme]
    layout, law = controller.law_gains, controller.gains[controller.common.size:]
    assert list(layout.shapes)[-len(names):] == names
    assert layout.offset(names[0]) == layout.size - len(names)
    values = {**controller.values}
    if scheme == "nn_adaptive_impedance":
        values["inv_variance"] = 1.0 / values["rbf_variance"]
    for name in names:
        assert layout.view(law, name)[0] == values[name], name
    assert not [a for a in dir(controller) if a.startswith("own_") or a == "OWN"]
    own_status = {"nn_adaptive_impedance": NN_STATUS_FIELDS}.get(scheme, [])
    if own_status:                                   # after the family's fields
        assert controller.status_fields[-len(own_status):] == own_status


def test_mrac_blocks_and_status_by_name():
    """The MRAC law's (4.72, 4.76-4.77) state and gains as Layouts, where its kernel read
    them by number before, and a run's status by name."""
    assert [mrac.STATE.offset(name) for name in mrac.STATE.shapes] == [
        0, 6, 12, 18, 20, 34, 35, 36, 37, 51, 52]
    assert [mrac.GAINS.offset(name) for name in mrac.GAINS.shapes] == [
        0, 6, 7, 8, 12, 13, 14, 15]
    assert (mrac.STATE_SIZE, mrac.GAINS_SIZE) == (53, 16)
    run = run_scheme("mrac_force", 0.2, {"f_d": 1.5})
    assert np.all(run.column("f_d_x") == 1.5)
    assert np.array_equal(run.column("tau_1"), run.command[:, 0])
    assert np.array_equal(run.column("f_err_x"), 1.5 - run.force[:, 0])
    controller = make_controller("mrac_force", {"f_d": 1.5})
    assert run.column("b3_hat")[0] == controller.values["b3_hat_0"]
    assert np.array_equal([run.column(f"{x}_hat")[0] for x in mrac.THETA_F_NAMES],
                          controller.values["theta_f_hat_0"])
