"""The learning-free estimator, one module per step: clusters, fits, ends, carry-back, motions, the pair's state and
the ego motion; `RigidFlowEstimator` runs them in order."""

from ssf_flow_node.core.rigid.config import RigidConfig
from ssf_flow_node.core.rigid.estimator import RigidFlowEstimator

__all__ = ["RigidConfig", "RigidFlowEstimator"]
