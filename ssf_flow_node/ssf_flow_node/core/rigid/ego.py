"""Step 1, the ego motion: aligned on every point, and without the mask's movers where it calls enough of them
dynamic; constant velocity (the previous pair's motion) judges between them, or the vehicle's measured motion where
it measured the pair's, which also vetoes an alignment the car cannot have driven."""

from __future__ import annotations

import numpy as np

from ssf_common.geometry.se3 import displacement_at
from ssf_flow_node.core.registration import motion_gap
from ssf_flow_node.core.rigid.config import RigidConfig
from ssf_flow_node.core.rigid.pair import PairState


def pair_ego_motion(state: PairState, dynamic: np.ndarray | None, config: RigidConfig) -> np.ndarray:
    """Ego motion aligned on every point (the robust kernel drops a few movers) and, where the mask calls more than
    `ego_refit` of the points dynamic, aligned without them. The second is taken at once where it is a change of
    the previous pair's motion a vehicle can make (constant velocity vouches for it, `ego_vouch`). Otherwise both
    are aligned: where they agree within `ego_tolerance`, the second (no movers); where they differ, the first,
    unless the second lies nearer the previous pair's ego motion by more than the tolerance, or only the second is
    a change a vehicle can make. A mask that hides static structure and keeps oncoming cars drags the second away
    step by step; traffic moving with the ego pulls the first towards standing still, a jump no vehicle makes
    between two scans."""
    if dynamic is None:  # a question without a mask leaves the stream's motion (the next pair's prior) as it was
        state.ego = every_point(state, config) if state.ego is None else state.ego
        return every_point(state, config)
    share = float(np.mean(dynamic)) if dynamic.size else 0.0
    if np.count_nonzero(dynamic) <= config.ego_refit * state.source.shape[0]:
        state.ego = every_point(state, config)
        return state.ego
    keep = np.ones(state.source.shape[0], bool)
    keep[: dynamic.size] = ~dynamic
    still = state.source[state.order[keep[state.order]]]
    masked = vetted(state, still, state.matcher.align(still, ordered=True, prior=state.prior), config)
    if config.ego_vouch and state.prior is not None and plausible(masked, state.prior, share, config):
        state.ego = masked
        return state.ego
    # made only to judge the masked one: where that one is a change of the previous pair's motion a vehicle can make,
    # restarting this one (from the other samples and that motion) cannot change the answer beyond a narrow case
    base = every_point(state, config, restarts=config.ego_judge_restarts or not steady(masked, state.prior, config))
    vouched = motion_gap(masked, base) <= config.ego_tolerance or (
        state.prior is not None and nearer_prior(masked, base, state.prior, config, share))
    state.ego = masked if vouched else base
    return state.ego

def every_point(state: PairState, config: RigidConfig, restarts: bool = True) -> np.ndarray:
    """The ego motion aligned on every point of the pair (once per pair; `restarts`: see ScanMatcher.align)."""
    if state.base_ego is None:
        source = state.source[state.order]
        state.base_ego = vetted(state, source, state.matcher.align(source, ordered=True, prior=state.prior,
                                                                   restarts=restarts), config)
    return state.base_ego


def vetted(state: PairState, source: np.ndarray, motion: np.ndarray, config: RigidConfig) -> np.ndarray:
    """An alignment, where it is one the car can have driven: within measured_gate at measured_range of the pair's
    measured motion (or nothing was measured). Else the refinement from the measured motion, where that one is; else
    the measured motion."""

    def near(candidate: np.ndarray) -> bool:
        return displacement_at(candidate, state.measured, config.measured_range) <= config.measured_gate

    if state.measured is None or near(motion):
        return motion
    again = state.matcher.refine(source, state.measured, ordered=True)
    return again if near(again) else state.measured

def plausible(motion: np.ndarray, prior: np.ndarray, dynamic_share: float, config: RigidConfig) -> bool:
    """Whether a motion is a change of the previous pair's that a vehicle can make in dt (ego_max_accel), aligned
    while the mask leaves most of the points to it (ego_mask_share)."""
    return steady(motion, prior, config) and dynamic_share <= config.ego_mask_share


def steady(motion: np.ndarray, prior: np.ndarray | None, config: RigidConfig) -> bool:
    """Whether a motion is a change of the previous pair's (None: none) that a vehicle can make in dt."""
    return prior is not None and motion_gap(motion, prior) <= config.ego_max_accel * config.scan_period ** 2

def nearer_prior(masked: np.ndarray, base: np.ndarray, prior: np.ndarray, config: RigidConfig,
                 dynamic_share: float = 0.0) -> bool:
    """Whether the alignment without the mask's dynamic points lies nearer the previous pair's motion than the one
    with every point by more than ego_tolerance, or is alone in being a change a vehicle can make in dt while the
    mask leaves most of the points to it (`dynamic_share`: the share it calls dynamic)."""
    alone_plausible = plausible(masked, prior, dynamic_share, config) and not plausible(base, prior, 0.0, config)
    return motion_gap(masked, prior) + config.ego_tolerance < motion_gap(base, prior) or alone_plausible
