"""Classical baselines with the Stable-Baselines3 ``predict`` interface, for every task.

* [`GeometricController`][vnhc_gym.baselines.GeometricController]: the stabilising law
  ``u* = C^-1 (-K phi - G(phi))`` from the observation and the nominal model (plain, or the
  sampled-data variant).
* [`ObserverController`][vnhc_gym.baselines.ObserverController]: the same law fed by a state
  observer (noisy observations).
* [`KalmanController`][vnhc_gym.baselines.KalmanController]: the same law fed by an extended Kalman
  filter (the nominal model's exact Jacobians, the environment's own observation noise).
* [`AdaptiveController`][vnhc_gym.baselines.AdaptiveController]: the law with the mismatched
  parameters estimated online.
* [`MPCController`][vnhc_gym.baselines.MPCController]: the planning baseline, model-predictive
  control of ``phi`` within the force bound on the nominal model.
* [`OracleController`][vnhc_gym.baselines.OracleController]: the headroom reference, the
  sampled-data law on the environment's true state and parameters (not an observation-based
  controller); [`InformedKalmanController`][vnhc_gym.baselines.InformedKalmanController], the
  Kalman-filter law told the true parameters but not the state, splits its headroom.
* [`SafetyFilter`][vnhc_gym.baselines.SafetyFilter]: any policy through a control barrier function
  on the task's velocity limits (its force changed as little as possible, only near a limit);
  [`SafeLaw`][vnhc_gym.baselines.SafeLaw] is the law through it.
* [`ActuatedLaw`][vnhc_gym.baselines.ActuatedLaw]: where the model is wrong in structure, the law
  on a predictor through the actuator (a bank identifying a delay or a lag online, a Smith
  predictor) with a disturbance observer; [`InformedActuatedLaw`][vnhc_gym.baselines.InformedActuatedLaw],
  the same law told the episode's hidden quantities, is a headroom reference.
* `ZeroPolicy` (no force) and `RandomPolicy` (uniform actions, seeded).

Every policy takes a single, wrapped or vector environment and predicts for one observation
``(d,)`` or a batch ``(n, d)``, returning float32 actions in ``[-1, 1]``.
"""

from vnhc_gym.baselines.actuated import ActuatedLaw, InformedActuatedLaw
from vnhc_gym.baselines.adaptive import AdaptiveController
from vnhc_gym.baselines.geometric import DEFAULT_GAIN, GeometricController
from vnhc_gym.baselines.kalman import InformedKalmanController, KalmanController
from vnhc_gym.baselines.mpc import MPCController
from vnhc_gym.baselines.observer import ObserverController
from vnhc_gym.baselines.oracle import OracleController
from vnhc_gym.baselines.policy import Policy, RandomPolicy, ZeroPolicy, task_of
from vnhc_gym.baselines.safety import SafeLaw, SafetyFilter
from vnhc_gym.baselines.tuning import CLASSICAL, REFERENCE, make_classical, tune

__all__ = ["ActuatedLaw", "AdaptiveController", "CLASSICAL", "DEFAULT_GAIN", "GeometricController",
           "InformedActuatedLaw", "InformedKalmanController", "KalmanController", "MPCController",
           "ObserverController", "OracleController", "Policy", "REFERENCE", "RandomPolicy", "SafeLaw",
           "SafetyFilter", "ZeroPolicy", "make_classical", "task_of", "tune"]
