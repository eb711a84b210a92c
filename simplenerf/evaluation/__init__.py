"""The evaluation protocol (SPEC 7): metrics, LPIPS, visibility masks, the test-time evaluator, tables, paper scores."""
