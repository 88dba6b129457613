"""A duckietown-sdk program for a container image built in the tests: the image carries its own SDK (at /opt/sdk,
on PYTHONPATH) and runs it on its own interpreter. It exits 6 unless it runs on the image's ``/usr/bin/python3``
with the image's duckietown-sdk and no proxybench importable, then runs ``sandboxed.py`` beside it (which checks
its sandbox and drives the lane as ``lane.py`` does; ``argv[1]``: the host's port it must not reach)."""
import importlib.util
import os
import sys

sdk = importlib.util.find_spec("duckietown")
where = [str(p) for p in sdk.submodule_search_locations or []] if sdk is not None else []
if sys.executable != "/usr/bin/python3" or importlib.util.find_spec("proxybench") is not None \
        or not where or not all(p.startswith("/opt/sdk/") for p in where):
    sys.stderr.write(f"not the image's interpreter and SDK: {sys.executable}, duckietown at {where}\n")
    sys.exit(6)
here = os.path.dirname(os.path.abspath(__file__))
path = os.path.join(here, "sandboxed.py")
with open(path) as f:
    exec(compile(f.read(), path, "exec"), {"__name__": "__main__", "__file__": path})
