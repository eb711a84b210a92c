"""The evaluation protocol: the test-time evaluator, visibility masks, reference and held-out SfM depth, rescoring."""
