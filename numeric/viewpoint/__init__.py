"""Viewpoint planning for environment information summarisation under a time limit
(Masuzawa & Miura).

One module per step of the paper: :mod:`appearance` (§3.2, eqs. 1-4: the appearance
model, the orientation posterior and P_recog), :mod:`recognition` (§3.1: simulated SIFT
matching and the measurements the model is fitted to), :mod:`grid` (§4.1: the free /
occupied / unknown map, its unknown regions and their entry points of §6.3); the
observation groups of §4.2 are Prolog rules (prolog/grouping.pl). Local planning (§5):
:mod:`viewpoints` (Fig. 7-8 and 9(b): S_obs, the patterns, S_par), :mod:`single`
(§5.1, eqs. 5-6), :mod:`sequential` (§5.2, eq. 7 for every subset of a group) and
:mod:`verification` (eq. 8, the local plan, and §5.3, eqs. 9-10). Global planning
(§6): :mod:`plan` (eqs. 11-14 and 18-20, the search of §6.4). :mod:`planner` runs one
planning request end to end (Fig. 2, the values of eqs. 15-17) and :mod:`online` the
summarisation loop of §7.3 in the simulator; :mod:`chizu.numeric.figures` draws them.
"""
