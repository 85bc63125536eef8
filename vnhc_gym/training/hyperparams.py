"""Hyperparameters in RL Baselines3 Zoo's own format, read without ``eval``.

The files are ``agents/hyperparams/<algo>.yml`` at the top of the repository, laid out exactly as
RL Zoo's ``hyperparams/<algo>.yml``: top-level keys are env ids, each section holds ``n_envs``,
``n_timesteps``, ``policy``, ``normalize``, ``env_wrapper``, ``policy_kwargs`` (a ``"dict(...)"``
string), schedules such as ``lin_3e-4`` and the algorithm's own arguments.  RL Zoo trains from
them unchanged::

    python -m rl_zoo3.train --algo ppo --env vnhc_gym/USVStream-v1 --gym-packages vnhc_gym \\
        --conf-file agents/hyperparams/ppo.yml

(residual PPO is ``--algo ppo --conf-file agents/hyperparams/residual_ppo.yml``, recurrent PPO
``--algo ppo_lstm --conf-file agents/hyperparams/recurrent_ppo.yml``: see `RL_ZOO_ALGO`).

RL Zoo turns the Python-expression strings into objects with ``eval``;
[`load_hyperparams`][vnhc_gym.training.hyperparams.load_hyperparams] reads the same files with
``yaml.safe_load`` and `parse_literal`, a parser (Python's `ast`) for exactly the subset those
strings use: ``dict(key=value, ...)``, ``{"key": value}``, lists, tuples, numbers, strings,
``True``/``False``/``None`` and ``nn.<Name>`` for the activation functions in `ALLOWED_NN`.
Anything else raises ``ValueError``.

When the package is installed, the files are found as the data-only subpackage
``vnhc_gym._hyperparams`` (``pyproject.toml`` maps it onto ``agents/hyperparams``); in a source
checkout, in ``agents/hyperparams`` next to the ``vnhc_gym`` folder (`hyperparams_dir`).
Importing this module imports neither torch nor Stable-Baselines3: resolving ``nn.<Name>``
imports ``torch.nn``, `make_schedule` imports Stable-Baselines3.
"""

from __future__ import annotations

import ast
import copy
import importlib.util
import math
import os
import re
from collections.abc import Mapping
from pathlib import Path
from typing import Any

__all__ = [
    "ALLOWED_NN",
    "RL_ZOO_ALGO",
    "RL_ZOO_KEYS",
    "SCHEDULE_KEYS",
    "available_algos",
    "dump_hyperparams",
    "env_ids",
    "hyperparams_dir",
    "hyperparams_path",
    "load_hyperparams",
    "make_schedule",
    "parse_literal",
]

#: ``torch.nn`` classes that ``nn.<Name>`` may name in a ``dict(...)`` string (activation functions).
ALLOWED_NN: frozenset[str] = frozenset({
    "CELU", "ELU", "GELU", "Hardswish", "Hardtanh", "Identity", "LeakyReLU", "Mish", "ReLU", "ReLU6",
    "SELU", "Sigmoid", "SiLU", "Softplus", "Softsign", "Tanh",
})

#: Hyperparameter file (``agents/hyperparams/<name>.yml``) -> RL Zoo's ``--algo``.  Residual PPO is
#: PPO with the ``vnhc_gym.wrappers.ResidualAction`` env wrapper (RL Zoo's ``--algo`` only takes its
#: own algorithm names); RecurrentPPO (sb3-contrib) is ``ppo_lstm`` in RL Zoo.
RL_ZOO_ALGO: dict[str, str] = {"ppo": "ppo", "residual_ppo": "ppo", "recurrent_ppo": "ppo_lstm", "sac": "sac",
                               "residual_sac": "sac"}

#: Keys RL Zoo takes itself (environment, wrappers, normalisation, budget); every other key of a
#: section is a keyword argument of the algorithm's constructor (``policy`` included).
RL_ZOO_KEYS: frozenset[str] = frozenset({
    "n_envs", "n_timesteps", "normalize", "env_wrapper", "vec_env_wrapper", "callback", "frame_stack",
    "env_kwargs", "monitor_kwargs", "noise_type", "noise_std",
})

#: Keys whose value may be a schedule string (``lin_<initial value>``), as in RL Zoo.
SCHEDULE_KEYS: tuple[str, ...] = ("learning_rate", "clip_range", "clip_range_vf", "delta_std")

_ALLOWED_TEXT = (
    "allowed: dict(key=value, ...), {'key': value, ...} with string keys, [lists], (tuples), numbers, "
    "strings, True/False/None and nn.<Name> for Name in " + ", ".join(sorted(ALLOWED_NN))
)

# Keys whose string value RL Zoo evaluates as a Python expression giving a dict.
_DICT_STRING_KEYS = ("policy_kwargs", "replay_buffer_kwargs", "monitor_kwargs")
_WRAPPER_KEYS = ("env_wrapper", "vec_env_wrapper", "callback")
_SCHEDULE_RE = re.compile(r"lin_(?P<value>.+)")


# --------------------------------------------------------------------------- the restricted parser
def parse_literal(text: str) -> Any:
    """The value of one of RL Zoo's Python-expression strings, without ``eval``.

    Accepts ``dict(key=value, ...)`` (keyword arguments only), ``{"key": value}`` with string
    keys, lists, tuples, numbers (with a sign), strings, ``True``/``False``/``None`` and
    ``nn.<Name>`` with ``Name`` in `ALLOWED_NN` (resolved to the ``torch.nn`` class, which
    imports torch), nested in any way, e.g.
    ``"dict(net_arch=dict(pi=[64, 64], vf=[64, 64]), activation_fn=nn.Tanh, log_std_init=-0.5)"``.

    Raises ``ValueError`` naming the text and the offending part for anything else (other names,
    other calls, attribute access, operators, ...).
    """
    if not isinstance(text, str):
        raise ValueError(f"expected a string to parse, got {type(text).__name__} {text!r}")
    source = text.strip()
    try:
        tree = ast.parse(source, mode="eval")
    except SyntaxError as e:
        raise ValueError(f"cannot parse {text!r}: not a Python expression ({e.msg}); {_ALLOWED_TEXT}") from None
    return _convert(tree.body, source, text)


def _reject(node: ast.AST, source: str, text: str, what: str) -> ValueError:
    part = ast.get_source_segment(source, node) or ast.dump(node)
    return ValueError(f"cannot parse {text!r}: {what} {part!r} is not allowed; {_ALLOWED_TEXT}")


def _convert(node: ast.AST, source: str, text: str) -> Any:
    if isinstance(node, ast.Constant):
        value = node.value
        if value is None or isinstance(value, (bool, int, float, str)):
            return value
        raise _reject(node, source, text, f"the {type(value).__name__} constant")
    if isinstance(node, ast.UnaryOp) and isinstance(node.op, (ast.USub, ast.UAdd)):
        operand = node.operand
        if (isinstance(operand, ast.Constant) and isinstance(operand.value, (int, float))
                and not isinstance(operand.value, bool)):
            return -operand.value if isinstance(node.op, ast.USub) else operand.value
        raise _reject(node, source, text, "the operation")
    if isinstance(node, ast.List):
        return [_convert(e, source, text) for e in node.elts]
    if isinstance(node, ast.Tuple):
        return tuple(_convert(e, source, text) for e in node.elts)
    if isinstance(node, ast.Dict):
        out: dict[str, Any] = {}
        for key, item in zip(node.keys, node.values, strict=True):
            if key is None:
                raise _reject(item, source, text, "the ** unpacking of")
            if not (isinstance(key, ast.Constant) and isinstance(key.value, str)):
                raise _reject(key, source, text, "the dictionary key (only string keys)")
            if key.value in out:
                raise _reject(key, source, text, "the repeated key")
            out[key.value] = _convert(item, source, text)
        return out
    if isinstance(node, ast.Call):
        if not (isinstance(node.func, ast.Name) and node.func.id == "dict"):
            raise _reject(node, source, text, "the call (only dict(...) calls)")
        if node.args:
            raise _reject(node.args[0], source, text, "the positional argument of dict(...)")
        kwargs: dict[str, Any] = {}
        for kw in node.keywords:
            if kw.arg is None:
                raise _reject(kw.value, source, text, "the ** unpacking of")
            if kw.arg in kwargs:
                raise _reject(kw, source, text, "the repeated keyword")
            kwargs[kw.arg] = _convert(kw.value, source, text)
        return kwargs
    if isinstance(node, ast.Attribute):
        if isinstance(node.value, ast.Name) and node.value.id == "nn" and node.attr in ALLOWED_NN:
            return _torch_nn_class(node.attr)
        raise _reject(node, source, text, "the attribute access (only nn.<Name>)")
    if isinstance(node, ast.Name):
        raise _reject(node, source, text, "the name")
    raise _reject(node, source, text, f"the {type(node).__name__} expression")


def _torch_nn_class(name: str) -> type:
    try:
        from torch import nn
    except ImportError as e:  # pragma: no cover - torch is in the "rl" extra
        raise ImportError(f"nn.{name} in a hyperparameter string needs torch (pip install vnhc-gym[rl])") from e
    cls: type = getattr(nn, name)
    return cls


# --------------------------------------------------------------------------- schedules
def make_schedule(value: str | float) -> Any:
    """The learning-rate / clip-range value SB3 takes for a hyperparameter value.

    ``"lin_3e-4"`` (RL Zoo's linear schedule) gives Stable-Baselines3's
    ``LinearSchedule(start=3e-4, end=0.0, end_fraction=1.0)``, i.e. ``progress_remaining * 3e-4``
    (from ``3e-4`` at the start of training to ``0`` at the end).  A number is returned as a float
    (SB3 makes a constant schedule of it).  Other strings raise ``ValueError`` (RL Zoo reads any
    ``<prefix>_<number>`` as linear; only ``lin_`` is accepted here).  Imports Stable-Baselines3.
    """
    if isinstance(value, bool) or not isinstance(value, (str, int, float)):
        raise ValueError(f"a schedule is a number or 'lin_<initial value>', got {value!r}")
    if isinstance(value, str):
        initial = _schedule_initial_value(value)
        from stable_baselines3.common.utils import LinearSchedule

        return LinearSchedule(start=initial, end=0.0, end_fraction=1.0)
    return float(value)


def _schedule_initial_value(text: str) -> float:
    match = _SCHEDULE_RE.fullmatch(text.strip())
    if match is not None:
        try:
            return float(match.group("value"))
        except ValueError:
            pass
    raise ValueError(f"invalid schedule {text!r}: a schedule string is 'lin_<initial value>', e.g. 'lin_3e-4'")


# --------------------------------------------------------------------------- where the files are
def hyperparams_dir() -> Path:
    """The folder of the hyperparameter files.

    The installed data package ``vnhc_gym._hyperparams`` (wheel, or editable install, which
    maps it onto the checkout's ``agents/hyperparams``) if there is one, else
    ``agents/hyperparams`` of the source checkout this module is in.
    """
    try:
        spec = importlib.util.find_spec("vnhc_gym._hyperparams")
    except (ImportError, ValueError):  # pragma: no cover - a broken installation
        spec = None
    if spec is not None:
        for location in spec.submodule_search_locations or ():
            folder = Path(location)
            if any(folder.glob("*.yml")):
                return folder
    checkout = Path(__file__).resolve().parents[2] / "agents" / "hyperparams"
    if checkout.is_dir():
        return checkout
    raise FileNotFoundError(
        "no hyperparameter files: neither the package data vnhc_gym._hyperparams nor a source checkout's "
        f"{checkout} exists (reinstall vnhc-gym, or pass path=...)"
    )


def available_algos() -> list[str]:
    """The names ``<algo>`` of the shipped ``<algo>.yml`` files."""
    return sorted(p.stem for p in hyperparams_dir().glob("*.yml"))


def hyperparams_path(algo: str) -> Path:
    """``<hyperparams_dir()>/<algo>.yml`` (``FileNotFoundError`` listing the algorithms if missing)."""
    if not re.fullmatch(r"[A-Za-z0-9_\-]+", algo):
        raise ValueError(f"invalid algorithm name {algo!r}")
    path = hyperparams_dir() / f"{algo}.yml"
    if not path.is_file():
        raise FileNotFoundError(f"no hyperparameters for algo {algo!r} ({path}); available: {available_algos()}")
    return path


def _read(path: str | os.PathLike[str]) -> dict[str, Any]:
    import yaml

    with open(path, encoding="utf-8") as f:
        doc = yaml.safe_load(f)
    if not isinstance(doc, dict):
        raise ValueError(f"{path}: expected a mapping of env ids to settings, got {type(doc).__name__}")
    return doc


def env_ids(algo: str, path: str | os.PathLike[str] | None = None) -> list[str]:
    """The env ids (top-level keys, RL Zoo's ``default`` / ``atari`` included) of a file."""
    return list(_read(hyperparams_path(algo) if path is None else path))


# --------------------------------------------------------------------------- writing
def _source(value: Any) -> str:
    """A value as RL Zoo's Python-expression strings write it (``nn.Tanh`` for a torch class)."""
    if isinstance(value, type):
        return f"nn.{value.__name__}"
    if isinstance(value, dict):
        return "dict(" + ", ".join(f"{k}={_source(v)}" for k, v in value.items()) + ")"
    if isinstance(value, list):
        return "[" + ", ".join(_source(v) for v in value) + "]"
    if isinstance(value, tuple):
        return "(" + ", ".join(_source(v) for v in value) + ("," if len(value) == 1 else "") + ")"
    return repr(value)


def dump_hyperparams(hp: dict[str, Any]) -> dict[str, Any]:
    """The inverse of `load_hyperparams` for one section: data back to RL Zoo's file form (the
    ``dict(...)`` strings, ``normalize``'s string, ``env_wrapper``'s ``{path: kwargs}`` items), so
    that ``load_hyperparams`` of the written section gives ``hp`` again and RL Zoo reads it."""
    out: dict[str, Any] = {}
    for key, value in hp.items():
        if key in _DICT_STRING_KEYS and isinstance(value, dict):
            out[key] = _source(value)
        elif key == "normalize" and isinstance(value, dict):
            out[key] = _source(value)
        elif key in _WRAPPER_KEYS and isinstance(value, list):
            out[key] = [{path: dict(kwargs)} if kwargs else path for path, kwargs in value]
        elif isinstance(value, tuple):
            out[key] = list(value)
        else:
            out[key] = value
    return out


# --------------------------------------------------------------------------- loading
def load_hyperparams(algo: str, env_id: str, path: str | os.PathLike[str] | None = None) -> dict[str, Any]:
    """The settings of ``env_id`` in ``agents/hyperparams/<algo>.yml`` (or in ``path``), as data.

    The section is chosen as RL Zoo does (the env id itself, else a ``default`` section) and
    RL Zoo's conversions are applied without evaluating code:

    * ``policy_kwargs`` (and ``replay_buffer_kwargs``, ``monitor_kwargs``) given as
      ``"dict(...)"`` strings: parsed by `parse_literal` into dicts, ``nn.Tanh`` etc. into
      the torch classes;
    * ``normalize``: ``True``/``False``, or a dict of ``VecNormalize`` arguments (from a mapping or
      a ``"dict(norm_obs=False, norm_reward=True)"`` string).  RL Zoo also passes the algorithm's
      ``gamma`` to ``VecNormalize``; that is left to the caller;
    * ``env_wrapper`` (and ``vec_env_wrapper``, ``callback``): a list of ``(import path, kwargs)``
      pairs, from any of RL Zoo's forms (a name, a list of names, ``{name: {kwargs}}`` items);
      ``None`` gives ``[]``.  Nothing is imported;
    * schedules (`SCHEDULE_KEYS`): numbers, or strings ``lin_<value>`` that are checked and
      left as strings (turn them into SB3 schedules with `make_schedule`);
    * ``n_timesteps``, ``n_envs`` as ints, ``train_freq`` lists as tuples.

    Every other key is returned as YAML gives it.  ``ValueError`` for a malformed value,
    ``KeyError`` if the file has neither ``env_id`` nor ``default``.
    """
    file = hyperparams_path(algo) if path is None else Path(path)
    doc = _read(file)
    if env_id in doc:
        section = doc[env_id]
    elif "default" in doc:
        section = doc["default"]
    else:
        raise KeyError(f"no hyperparameters for {env_id!r} in {file}; it has {sorted(map(str, doc))}")
    if not isinstance(section, dict):
        raise ValueError(f"{file}: the section of {env_id!r} is not a mapping: {section!r}")
    return _postprocess(copy.deepcopy(section), f"{file} [{env_id}]")


def _postprocess(hp: dict[str, Any], where: str) -> dict[str, Any]:
    for key in _DICT_STRING_KEYS:
        if isinstance(hp.get(key), str):
            hp[key] = _parse_dict(hp[key], key, where)
    if "normalize" in hp:
        hp["normalize"] = _parse_normalize(hp["normalize"], where)
    for key in _WRAPPER_KEYS:
        if key in hp:
            hp[key] = _parse_wrappers(hp[key], key, where)
    for key in SCHEDULE_KEYS:
        if key in hp:
            value = hp[key]
            if isinstance(value, str):
                try:
                    _schedule_initial_value(value)
                except ValueError as e:
                    raise ValueError(f"{where}: {key}: {e}") from None
            elif isinstance(value, bool) or not isinstance(value, (int, float)):
                raise ValueError(f"{where}: {key} must be a number or 'lin_<value>', got {value!r}")
    for key in ("n_timesteps", "n_envs"):
        if key in hp:
            hp[key] = _as_int(hp[key], key, where)
    if isinstance(hp.get("train_freq"), list):
        hp["train_freq"] = tuple(hp["train_freq"])
    return hp


def _parse_dict(text: str, key: str, where: str) -> dict[str, Any]:
    try:
        value = parse_literal(text)
    except ValueError as e:
        raise ValueError(f"{where}: {key}: {e}") from None
    if not isinstance(value, dict):
        raise ValueError(f"{where}: {key} must give a dict, {text!r} gives {type(value).__name__}")
    return value


def _parse_normalize(value: Any, where: str) -> bool | dict[str, Any]:
    if isinstance(value, bool):
        return value
    if isinstance(value, str):
        return _parse_dict(value, "normalize", where)
    if isinstance(value, Mapping) and all(isinstance(k, str) for k in value):
        return dict(value)
    raise ValueError(f"{where}: normalize must be true/false, a mapping or a 'dict(...)' string, got {value!r}")


def _parse_wrappers(value: Any, key: str, where: str) -> list[tuple[str, dict[str, Any]]]:
    if value is None:
        return []
    items = value if isinstance(value, list) else [value]
    out: list[tuple[str, dict[str, Any]]] = []
    for item in items:
        kwargs: Any
        if isinstance(item, str):
            name, kwargs = item, {}
        elif isinstance(item, dict) and len(item) == 1:
            name, kwargs = next(iter(item.items()))
            if not isinstance(kwargs, dict):
                raise ValueError(f"{where}: {key}: the arguments of {name!r} must be a mapping, got {kwargs!r}")
        else:
            raise ValueError(f"{where}: {key}: expected 'module.Class' or {{module.Class: {{kwargs}}}}, got {item!r}")
        if not (isinstance(name, str) and re.fullmatch(r"[A-Za-z_]\w*(\.[A-Za-z_]\w*)+", name)):
            raise ValueError(f"{where}: {key}: {name!r} is not an import path 'module.Class'")
        out.append((name, dict(kwargs)))
    return out


def _as_int(value: Any, key: str, where: str) -> int:
    if (isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value)
            or value != int(value) or value < 1):
        raise ValueError(f"{where}: {key} must be a positive whole number, got {value!r}")
    return int(value)


def checked_section(hp: Mapping[str, Any], known: frozenset[str], known_policy_kwargs: frozenset[str], trainer: str,
                    where: str) -> dict[str, Any]:
    """A file's section checked against what a trainer reads; returns its ``policy_kwargs``.

    Raises
    ------
    ValueError
        Naming every key of the section (and of its ``policy_kwargs``) outside ``known``
        (``known_policy_kwargs``), and a policy other than ``MlpPolicy``: a key a trainer does not
        implement is an error, never ignored.
    """
    unknown = sorted(set(hp) - known)
    if unknown:
        raise ValueError(f"{where}: {trainer} does not implement {unknown}; it reads {sorted(known)} "
                         f"(train with backend 'sb3' for the others)")
    if hp.get("policy", "MlpPolicy") != "MlpPolicy":
        raise ValueError(f"{where}: {trainer} trains an MlpPolicy, got policy {hp['policy']!r}")
    policy_kwargs = dict(hp.get("policy_kwargs") or {})
    unknown = sorted(set(policy_kwargs) - known_policy_kwargs)
    if unknown:
        raise ValueError(f"{where}: policy_kwargs {unknown} are not implemented by {trainer} "
                         f"(it reads {sorted(known_policy_kwargs)})")
    return policy_kwargs
