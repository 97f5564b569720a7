"""Why a stop was not answered: which of the paper's tests held the turn back.

A turn leaves the state X only through a localizable region (Maeda & Shirai §2.4,
eq. 6) and becomes Z only through a unique vote (§2.5) outside any candidate-multiple
set (§3.3). When a stop ends without an answer, exactly one of these is the first to
refuse it, in this order:

``no_region``
    no image's D_err = c_a d / sqrt(A) fell below D_thd for any triplet (eq. 6): the
    turn is outside every localizable region, or c_a calibrated the region narrower
    than where the robot stands.
``plane_test``
    some image passed eq. 6 on d, but none lay near its triplet's plane (eq. 4), the
    bound on what eq. 5's interpolation may place off.
``vote_threshold``
    the hits' weight 1 - D_err / D_thd adds up to less than the votes a group needs.
``vote_margin``
    two groups of candidates disagree and the leader does not lead by the margin.
``candidate_set``
    every hit so far lies in one candidate-multiple set: look-alike places (§3.3).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from chizu.numeric.eigenspace.localization import RegionModel, Session, Vote
from chizu.numeric.eigenspace.regions import estimation_error, triplet_differences

REFUSALS = ("no_region", "plane_test", "vote_threshold", "vote_margin", "candidate_set")


@dataclass(frozen=True)
class Refusal:
    """The first test that refused a stop, and the figure it refused on: the smallest
    D_err of the turn [m] (``no_region``, ``plane_test``) or the winner's votes and the
    best rival's (``vote_threshold``, ``vote_margin``, ``candidate_set``)."""

    reason: str
    d_err_min_m: float | None = None
    votes: float | None = None
    rival_votes: float | None = None


def refusal(regions: RegionModel, session: Session, vote: Vote) -> Refusal | None:
    """Why the session, after its latest stop, has no unique answer; None when it has
    one. Without any hit so far, eq. 6 is judged on the latest turn's projections."""
    if vote.unique:
        return None
    if len(session.pose0) == 0:
        d_err = np.inf
        if session.last_turn is not None and len(regions.triplets):
            d = triplet_differences(regions.model, regions.triplets, session.last_turn)
            d_err = float(estimation_error(d, regions.triplets.area[None, :],
                                           regions.c_a).min())
        reason = "plane_test" if d_err < regions.d_thd_m else "no_region"
        return Refusal(reason, d_err_min_m=float(d_err))
    assert vote.refused is not None and vote.winner is not None
    return Refusal(vote.refused, votes=float(vote.votes[vote.winner]),
                   rival_votes=vote.rival_votes)
