"""Pure control math for torquelab: dynamics snapshots, coupling metrics, controllers, estimators.

Depends only on numpy, pinocchio and osqp; never on the simulator or the web UI.
"""
