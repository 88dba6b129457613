"""``proxybench rank``: K agents ranked on the target with a guarantee, the proxy as the predictor."""
