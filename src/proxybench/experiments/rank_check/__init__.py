"""``proxybench rank-check``: does rank's guarantee hold on many targets, and what does the proxy save there?"""
