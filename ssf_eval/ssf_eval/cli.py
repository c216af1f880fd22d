"""`ssf eval` and `ssf bench` commands of every stage that needs the simulator or several cores together (and the
flow cached for training the segmentation networks)."""

from __future__ import annotations

from ssf_common.command_groups import CommandGroups


def register(groups: CommandGroups) -> None:
    """Add the evaluation and benchmark commands."""
    from ssf_eval import training_flow
    from ssf_eval.flow import cli as flow
    from ssf_eval.nav import cli as nav
    from ssf_eval.odom import cli as odom
    from ssf_eval.plan import cli as plan
    from ssf_eval.seg import cli as seg
    from ssf_eval.sensors import cli as sensors

    flow.register(groups)
    seg.register(groups)
    nav.register(groups)
    plan.register(groups)
    odom.register(groups)
    sensors.register(groups)
    training_flow.register(groups)
