"""Eigenspace localization with movement and learning strategies (Maeda & Shirai).

One module per step of the paper: :mod:`learning` (§2.1, eqs. 1-3),
:mod:`interpolation` (§2.2, eqs. 4-5), :mod:`triplets` (§2.3), :mod:`regions` (§2.4,
eq. 6; §3.2, eq. 7; §3.3), :mod:`localization` (§2.5, §3.4), :mod:`movement_strategy`
(§3.5, eqs. 8-11), :mod:`learning_strategy` (§4.2) and :mod:`analysis`, which runs
them in order.
"""
