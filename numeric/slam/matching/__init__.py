"""The scan matchers both estimators share.

- :mod:`~chizu.numeric.slam.matching.intensity_icp`: Intensity-ICP (Hara et al. §4, eqs. 1-3),
  point-to-line with the received-light intensity as a third coordinate;
- :mod:`~chizu.numeric.slam.matching.correlative`: correlative search on a probability grid
  (Olson 2009) and its branch-and-bound form over precomputed max-pooled grids (Hess et
  al. 2016, §V, Algorithms 2-3);
- :mod:`~chizu.numeric.slam.matching.likelihood_field`: scan matching on keyframe likelihood
  fields (eqs. 8-9's measurement model), the matcher of the RBPF's improved proposal.
"""
