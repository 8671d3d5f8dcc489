"""The paper's two baselines (Sec. V-C): NN point differencing (`nn.py`) and a panoptic multi-TSDF
style submap comparison (`tsdf.py`), and `ndfa eval`, which scores them beside ndfa (`table.py`).

Both baselines are given what the paper gave them and ndfa does without: the true camera poses
and ground-truth associations (the instance masks; an instance id is one physical object in both
sessions). `common.py` holds what they share: the decision record, the streaming protocol and
the checks that a recording can feed them.
"""

from ndfa.eval.baselines.common import Baseline, BaselineDecision, BaselineError, run_baseline, true_pose

__all__ = ["Baseline", "BaselineDecision", "BaselineError", "run_baseline", "true_pose"]
