"""`--policy.type=gc_dp3`: the goal-conditioned DP3 policy that executes a predicted goal cloud (cloth)."""
