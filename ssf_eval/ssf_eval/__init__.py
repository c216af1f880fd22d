"""Evaluation and benchmarks of SSF-PAN: the one package that imports both the simulator and the stages' cores.

| module | what |
| --- | --- |
| `sources` | labelled pairs from a simulator scenario + seed, an exported folder, or a recorded bag |
| `results` | strict JSON results with the effective config beside them |
| `flow/` | `ssf eval flow`, `ssf bench flow`: metrics, the estimator table, the error picture |
| `odom/` | `ssf odom run` (scans or a bag with the project's own flow and segmentation), `ssf eval odom` (evo RPE/ATE, drift, map trails, KISS-ICP beside), `ssf bench odom` |
"""
