"""Contact-sampling synthesis of finger motion (Ye & Liu 2012): search state, node tests, the randomized search,
reconstruction of smooth motion and the result files."""

DEFAULT_MAX_NODES = 60000
"""The default node budget of :func:`~torchhand.synthesis.pipeline.synthesize` and ``torchhand synthesize`` (node
tests, i.e. frames tested by the search): enough for ten solutions of the built-in scenes on most seeds
(BENCHMARKS.md), the same answer on any machine."""
