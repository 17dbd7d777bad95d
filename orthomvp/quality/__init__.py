"""How good the visibility flags are. The truth-free check on your own data, by the NCC of
orthophoto pairs at posts called visible and occluded (:mod:`.check`), and the epsilon study
against a synthetic scene's exact truth (:mod:`.eps_study`)."""
