"""An evaluator for the queue race (``support.queue_race``), run as its own process so that it can be killed -9.

    python race_evaluator.py URL NAME ACK_FILE LEASE_SECONDS SEED      # token in $PROXYBENCH_TOKEN

It leases a job, "works" for a random time around the lease's length without a heartbeat (so about half
of its results arrive after the lease lapsed, racing the server's reaper), then posts a success. Every
result posted is appended to ACK_FILE as ``job_id lease_id late acknowledged|refused`` (``late``: 1 if it
was posted after its lease had lapsed) before the next lease; a post refused with 409 is a lost race, not
an error.
"""

from __future__ import annotations

import os
import random
import sys
import time

from proxybench.client import ServerClient, ServerError

SCORES = {"driven_lanedir_consec_median": 5.0, "survival_time_median": 60.0,
          "deviation_center_line_median": 0.1, "in_drivable_lane_median": 0.0}


def main(url: str, name: str, ack_file: str, lease_seconds: float, seed: int) -> None:
    rng = random.Random(seed)
    with ServerClient(url, os.environ["PROXYBENCH_TOKEN"], retry_for=60.0) as c, open(ack_file, "a") as acks:
        while True:
            try:
                job = c.lease(name, ["sim"])
            except ServerError:
                time.sleep(0.2)
                continue
            if job is None:
                time.sleep(0.05)
                continue
            work = rng.uniform(0.5, 1.5) * lease_seconds
            time.sleep(work)
            body = {"evaluator": name, "lease_id": job.lease_id, "status": "success", "public_scores": SCORES,
                    "hidden_scores": SCORES}
            late = int(work > lease_seconds)
            try:
                c.result(job.job_id, body)
            except ServerError as exc:
                if exc.status != 409:
                    print(f"{name}: job {job.job_id}: {exc}", file=sys.stderr, flush=True)
                acks.write(f"{job.job_id} {job.lease_id} {late} refused\n")  # the lease was lost: refused
                acks.flush()
                continue
            acks.write(f"{job.job_id} {job.lease_id} {late} acknowledged\n")
            acks.flush()


if __name__ == "__main__":
    main(sys.argv[1], sys.argv[2], sys.argv[3], float(sys.argv[4]), int(sys.argv[5]))
