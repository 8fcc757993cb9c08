"""Stage 8, evaluation: how well the estimators do, on data whose answer is known.

The paper-reproduction and validation protocols on synthetic scenes
(:mod:`calib.evaluation.synthetic`), every method side by side (:mod:`calib.evaluation.compare`,
its report in :mod:`calib.evaluation.compare_report`) and lamp planning
(:mod:`calib.evaluation.lamp_planning`). ``calib.evaluation`` imports the stages before it
(:mod:`calib.core` to :mod:`calib.pipeline`), never the command line.
"""
