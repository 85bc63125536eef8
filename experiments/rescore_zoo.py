"""Score every shipped agent again on its test episodes and write the scores into its sidecar.

The shipped agents' sidecars (``vnhc_gym/agents_zoo/<task>-<algo>.json``) carry the scores of their
test episodes (seeds from 10000), which a test holds each agent to.  Those episodes are drawn by the
environments' random streams; this script re-measures every agent on them (the same protocol as at
the end of training: `vnhc_gym.evaluation.evaluate`, deterministic actions) and rewrites the
``test`` record, leaving the agent itself and the rest of its record as they are.

    python experiments/rescore_zoo.py
"""

from __future__ import annotations

import json

from vnhc_gym.evaluation import evaluate
from vnhc_gym.training.agents import ZOO_DIR, list_zoo, load_agent
from vnhc_gym.training.config import jsonable


def main() -> None:
    for name in list_zoo():
        path = ZOO_DIR / f"{name}.json"
        side = json.loads(path.read_text())
        rec = side["test"]
        result = evaluate(load_agent(name), side["env_id"], side.get("scenario", "nominal"),
                          n_episodes=rec["n_episodes"], seed=rec["seed"])
        new = {k: v for k, v in result.to_dict().items() if k in ("metrics", "summary", "seed", "n_episodes")}
        side["test"] = jsonable(new)
        print(f"{name}: mean |phi| {rec['summary']['mean_abs_phi'][0]} -> {side['test']['summary']['mean_abs_phi'][0]}")
        path.write_text(json.dumps(side, indent=1) + "\n")


if __name__ == "__main__":
    main()
