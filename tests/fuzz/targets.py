"""Fuzz targets: every decoder and file reader of the project, fed mutated valid inputs.

A target is a reader, the exceptions it may raise for bad input, and valid seed inputs. The
hypothesis strategies of :mod:`tests.fuzz.strategies` mutate the seeds (bytes, text lines,
JSON structure); :func:`exercise` feeds one input and counts the outcome per target in
:data:`COUNTS` (``accepted`` or ``rejected``). Any other exception escapes: that is a finding.
"""

from __future__ import annotations

import json
import random
import re
import shutil
import tempfile
import threading
import traceback
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass, field
from functools import cache
from pathlib import Path

import numpy as np

from teleop_force.errors import DataError, MessageError, ModelError, ModelFileError
from teleop_force.identification.dynamic_model import DynamicModel
from teleop_force.io.interchange_csv import Recording, read_interchange_csv, write_interchange_csv
from teleop_force.io.mcap_session import SessionReader, SessionWriter, read_session_as_recording
from teleop_force.models import DEFAULT_MODEL_PATH
from teleop_force.transport import keys
from teleop_force.transport import messages as m

#: Outcomes per target name: {"accepted": n, "rejected": n}.
COUNTS: dict[str, Counter[str]] = {}
_LOCK = threading.Lock()
_WORK = Path(tempfile.mkdtemp(prefix="teleop-fuzz-"))


@dataclass(frozen=True)
class KnownIssue:
    """A finding reported to the module's owner, not fixed yet: counted, not failed on.

    It matches only an exception of exactly ``kind`` whose message matches ``pattern`` and
    whose traceback passes through one of ``modules``: anything else still fails the test.
    """

    ident: str
    kind: type[BaseException]
    pattern: str
    modules: tuple[str, ...]

    def matches(self, exc: BaseException) -> bool:
        """Whether ``exc`` is this issue."""
        if type(exc) is not self.kind or not re.search(self.pattern, str(exc)):
            return False
        frames = traceback.extract_tb(exc.__traceback__)
        return any(m in frame.filename for frame in frames for m in self.modules)


@dataclass(frozen=True)
class Target:
    """One reader under fuzzing."""

    name: str
    run: Callable[[bytes], object]
    allowed: tuple[type[BaseException], ...]
    seeds: Callable[[], list[bytes]] = field(repr=False)
    known: tuple[KnownIssue, ...] = ()


def exercise(target: Target, data: bytes) -> str:
    """Feed ``data`` to ``target``; count and return the outcome; let other errors escape."""
    try:
        target.run(data)
    except target.allowed:
        outcome = "rejected"
    except Exception as exc:
        issue = next((k for k in target.known if k.matches(exc)), None)
        if issue is None:
            raise
        outcome = f"known issue {issue.ident}"
    else:
        outcome = "accepted"
    with _LOCK:
        COUNTS.setdefault(target.name, Counter())[outcome] += 1
    return outcome


def _scratch(name: str, data: bytes) -> Path:
    """Write ``data`` to a per-thread scratch file named ``name``."""
    folder = _WORK / str(threading.get_ident())
    folder.mkdir(exist_ok=True)
    path = folder / name
    path.write_bytes(data)
    return path


# --------------------------------------------------------------------------- wire messages


def message_examples() -> list[m.Message]:
    """One or more valid messages of every type (edge cases included)."""
    t = 1_700_000_000_123_456_789
    return [
        m.JointState(1, t, (0.1, 0.8, 0.3), (0.0, -0.5, 1.0), (0.01, 0.2, -0.05)),
        m.JointState(2**32 - 1, -1, (0.0,), (0.0,), (0.0,)),
        m.JointState(3, t, tuple(np.linspace(-1, 1, 9)), (0.0,) * 9, (1e-300,) * 9),
        m.JointSetpoint(4, t, (0.1, 0.8, 0.3)),
        m.ContactForce(5, t, (0.0, -1.5, 0.25)),
        m.ForceEstimateMessage(
            6,
            t,
            5,
            (float("nan"),) * 3,
            (0.1, 0.2, 0.3),
            (True, False, True),
            (1.0, 0.0, 0.5),
            (0.1, 0.2, 0.3),
            (0.0, 0.1, 0.2),
        ),
        m.ForceEstimateMessage(
            7, t, 6, (1.0, 2.0, 3.0), (0.1,) * 9, (True,) * 9, (1.0,) * 9, (0.0,) * 9, (0.0,) * 9
        ),
        m.Status(8, t, m.SafetyState.HOLDING, "master setpoint stale: 51.0 ms > 50 ms"),
        m.Status(9, t, m.SafetyState.FOLLOWING, "héllo ✓"),
    ]


def _decode_any(data: bytes) -> object:
    return m.decode(data)


def _decode_each(data: bytes) -> object:
    """Every class's decoder on the same bytes; rejected if any rejects (all must be clean)."""
    failures = 0
    for cls in m.MESSAGE_CLASSES.values():
        try:
            cls.decode(data)
        except MessageError:
            failures += 1
    if failures == len(m.MESSAGE_CLASSES):
        raise MessageError("no class accepts it")
    return None


def _from_json(data: bytes) -> object:
    try:  # what a session reader does before from_json_dict (it reports DataError)
        value = json.loads(data)
    except (ValueError, RecursionError) as exc:
        raise MessageError(f"not JSON: {exc}") from None
    accepted = 0
    for cls in m.MESSAGE_CLASSES.values():
        try:
            cls.from_json_dict(value)
            accepted += 1
        except MessageError:
            continue
    if not accepted:
        raise MessageError("no class accepts it")
    return None


def _message_seeds() -> list[bytes]:
    return [x.encode() for x in message_examples()]


def _ros2_decoders():
    from teleop_force.ros2 import codec
    from teleop_force.ros2.attachment import Attachment
    from teleop_force.ros2.graph import parse_token

    return (
        lambda p: codec.decode_joint_state(p, 1),
        lambda p: codec.decode_joint_setpoint(p, 1),
        codec.decode_wrench,
        lambda p: codec.decode_contact_force(p, 1),
        codec.decode_estimate_diagnostics,
        lambda p: codec.decode_status(p, 1),
        lambda p: codec.decode_service_diagnostics(p, 1),
        Attachment.decode,
        lambda p: parse_token(p.decode("utf-8", "replace")),
    )


def _decode_ros2(data: bytes) -> object:
    """Every ROS 2 decoder (CDR payloads, the attachment, a token) on the same bytes."""
    results = []
    for decode in _ros2_decoders():
        try:
            results.append(decode(data))
        except MessageError as exc:
            results.append(exc)
    if all(isinstance(r, MessageError) for r in results):
        raise results[0]
    return results


def _ros2_seeds() -> list[bytes]:
    from teleop_force.ros2 import codec
    from teleop_force.ros2.attachment import Attachment
    from teleop_force.ros2.topics import OMNI_MODEL_JOINT_NAMES

    examples: dict[type, m.Message] = {}
    for example in message_examples():  # the first, 3-joint one of each type
        examples.setdefault(type(example), example)
    estimate = examples[m.ForceEstimateMessage]
    seeds = [
        codec.encode_joint_state(examples[m.JointState], OMNI_MODEL_JOINT_NAMES),
        codec.encode_joint_setpoint(examples[m.JointSetpoint], OMNI_MODEL_JOINT_NAMES),
        codec.encode_contact_force(examples[m.ContactForce], "base"),
        *codec.encode_estimate(estimate, OMNI_MODEL_JOINT_NAMES, "base"),
        codec.encode_status(examples[m.Status]),
        Attachment(1, 2, bytes(range(16))).encode(),
        (b"@ros2_lv/0/aac3/0/1/MP/%/%/n/%t/std_msgs::msg::dds_::String_/RIHS01_00/::,7:,:,:,,"),
    ]
    return seeds


def _message_json_seeds() -> list[bytes]:
    return [json.dumps(x.to_json_dict()).encode() for x in message_examples()]


# --------------------------------------------------------------------------- MCAP sessions


@cache
def _mcap_seed_bytes() -> tuple[bytes, ...]:
    """Small session files: zstd and uncompressed, several chunks, and one cut mid-way."""
    out = []
    for compression in ("zstd", "none"):
        path = _WORK / f"seed-{compression}.mcap"
        with SessionWriter(
            path, {"primary_device": "s"}, chunk_size_bytes=1024, compression=compression
        ) as writer:
            for k in range(12):
                t = 1_700_000_000_000_000_000 + k * 1_000_000
                q = (0.1 * k, 0.8, 0.3)
                writer.write(
                    keys.measured_js("s"), m.JointState(k, t, q, (0.0,) * 3, (0.1,) * 3), t
                )
                writer.write(keys.measured_cf("s"), m.ContactForce(k, t, (0.0, -0.1 * k, 0.0)), t)
                if k % 4 == 0:
                    writer.write(keys.status("s"), m.Status(k, t, m.SafetyState.FOLLOWING), t)
                    writer.write(keys.setpoint_js("m"), m.JointSetpoint(k, t, q), t)
        out.append(path.read_bytes())
    out.append(out[0][: len(out[0]) * 2 // 3])  # a writer killed mid-session
    return tuple(out)


def _read_mcap(data: bytes) -> object:
    path = _scratch("fuzz.mcap", data)
    reader = SessionReader(path)
    _ = (len(reader), reader.topics, reader.message_counts, reader.devices(), reader.truncated)
    for _item in reader.messages():
        pass
    return read_session_as_recording(path)


# --------------------------------------------------------------------------- interchange CSV


@cache
def _csv_seed_bytes() -> tuple[bytes, ...]:
    t = np.arange(12) * 1e-3
    q = np.column_stack([0.1 * np.sin(t * 5), 0.8 + t, 0.3 - t])
    tau = np.column_stack([0.01 * np.cos(t), 0.2 + 0 * t, -0.05 + t])
    force = np.column_stack([0 * t, -t, 0.5 + 0 * t])
    seeds = []
    for with_force in (True, False):
        path = _WORK / f"seed-{with_force}.csv"
        recording = Recording(t, q, tau, force if with_force else None)
        write_interchange_csv(path, recording)
        seeds.append(path.read_bytes())
    seeds.append(b"tau1,t,q1,extra\n0.1,0,0.2,x\n0.2,0.001,0.3,y\n")
    return tuple(seeds)


def _read_csv(data: bytes) -> object:
    return read_interchange_csv(_scratch("fuzz.csv", data))


# --------------------------------------------------------------------------- robot files

ROBOT_DH = {
    "format": "teleop-force-robot",
    "version": 1,
    "name": "three-link",
    "joint_names": ["yaw", "pitch", "elbow"],
    "gravity_mps2": [0.0, -9.81, 0.0],
    "coupling": [[1, 0, 0], [0, 1, 0], [0, -1, 1]],
    "rotor_inertia_kgm2": [1e-4, 2e-4, 3e-4],
    "friction_inputs": [[1], [2, 3], [2, 3]],
    "q_min_rad": [-1.0, 0.0, -0.8],
    "q_max_rad": [1.0, 1.7, 1.2],
    "springs": [{"joint": 2, "rest_angle_rad": 1.5}],
    "dh": {
        "tip_offset_m": [0.0, 0.0, 0.05],
        "rows": [
            {"alpha_rad": 1.5707963267948966, "a_m": 0.0, "d_m": 0.1, "mass_kg": 0.3},
            {
                "alpha_rad": 0.0,
                "a_m": 0.2,
                "d_m": 0.0,
                "theta_offset_rad": 0.3,
                "mass_kg": 0.2,
                "com_m": [-0.1, 0, 0],
            },
            {
                "alpha_rad": 0.0,
                "a_m": 0.15,
                "d_m": 0.0,
                "mass_kg": 0.1,
                "type": "revolute",
                "inertia_kgm2": [[1e-4, 0, 0], [0, 1e-4, 0], [0, 0, 1e-4]],
            },
        ],
    },
}

ROBOT_TOML = b"""format = "teleop-force-robot"
version = 1
name = "two-link"
coupling = [[1, 0], [-1, 1]]
q_min_rad = [-1.0, 0.0]
q_max_rad = [1.0, 1.7]
springs = [{ joint = 1, rest_angle_rad = 0.5 }]

[dh]
tip_offset_m = [0.0, 0.0, 0.05]
rows = [
  { alpha_rad = 1.5707963267948966, a_m = 0.0, d_m = 0.1, mass_kg = 0.3 },
  { alpha_rad = 0.0, a_m = 0.2, d_m = 0.0, theta_offset_rad = 0.3, mass_kg = 0.2 },
]
"""

URDF = b"""<?xml version="1.0"?>
<robot name="arm">
  <link name="base"><inertial><mass value="1.0"/><inertia ixx="0.01" ixy="0" ixz="0" iyy="0.01" iyz="0" izz="0.01"/></inertial></link>
  <joint name="hip" type="revolute"><parent link="base"/><child link="thigh"/><axis xyz="0 1 0"/>
    <limit effort="10" lower="-3" upper="3" velocity="10"/></joint>
  <link name="thigh"><inertial><origin xyz="0 0 -0.1"/><mass value="0.2"/><inertia ixx="0.001" ixy="0" ixz="0" iyy="0.001" iyz="0" izz="0.0001"/></inertial></link>
  <joint name="knee" type="revolute"><parent link="thigh"/><child link="shin"/><origin xyz="0 0 -0.2"/><axis xyz="0 1 0"/>
    <limit effort="10" lower="-3" upper="3" velocity="10"/></joint>
  <link name="shin"><inertial><origin xyz="0 0 -0.1"/><mass value="0.1"/><inertia ixx="0.001" ixy="0" ixz="0" iyy="0.001" iyz="0" izz="0.0001"/></inertial></link>
  <joint name="ankle" type="fixed"><parent link="shin"/><child link="foot"/><origin xyz="0 0 -0.2"/></joint>
  <link name="foot"/>
</robot>
"""  # noqa: E501

ROBOT_URDF_DESCRIPTION = {
    "format": "teleop-force-robot",
    "version": 1,
    "name": "leg",
    "tip_frame": "foot",
    "urdf": {"path": "arm.urdf", "joints": ["hip", "knee"]},
}

#: Scratch-file suffix of a robot input: the first byte of the fuzzed input picks it.
_ROBOT_KINDS = (".json", ".toml", ".urdf")


def robot_input(kind: str, body: bytes) -> bytes:
    """Pack a robot input: one byte naming the kind (json, toml, urdf), then the file."""
    return bytes([_ROBOT_KINDS.index(kind)]) + body


def _read_robot(data: bytes) -> object:
    from teleop_force.robots.file import load_robot_description

    if not data:
        raise DataError("empty input")
    kind = _ROBOT_KINDS[data[0] % len(_ROBOT_KINDS)]
    body = data[1:]
    if kind == ".urdf":  # the URDF is the fuzzed file, the description naming it is valid
        _scratch("arm.urdf", body)
        path = _scratch("robot.json", json.dumps(ROBOT_URDF_DESCRIPTION).encode())
    else:
        _scratch("arm.urdf", URDF)
        path = _scratch(f"robot{kind}", body)
    return load_robot_description(path)


def _robot_seeds() -> list[bytes]:
    return [
        robot_input(".json", json.dumps(ROBOT_DH).encode()),
        robot_input(".toml", ROBOT_TOML),
        robot_input(".urdf", URDF),
    ]


# --------------------------------------------------------------------------- model files


@cache
def model_seed_dicts() -> tuple[dict, ...]:
    """The shipped model with its coupled-CV fallback as the friction, a wavelet-network model
    (untrained, with that fallback) and the coupled-CV model as ``robot none``."""
    import dataclasses

    from teleop_force.friction.wavelet_network import WaveletNetwork, omni_wavelet_specs

    shipped = DynamicModel.load(DEFAULT_MODEL_PATH)
    assert isinstance(shipped.friction, WaveletNetwork) and shipped.friction.fallback is not None
    model = dataclasses.replace(shipped, friction=shipped.friction.fallback)
    network = WaveletNetwork(3, omni_wavelet_specs(), fallback=model.friction)
    wn = DynamicModel(
        model.robot, model.n_joints, model.filter_config, model.base, model.base_values,
        model.base_std, network, model.offsets_nm,
    )  # fmt: skip
    cv_none = json.loads(json.dumps(model.to_dict()))
    cv_none.update(robot="none", base=None, base_names=[], base_values=[], base_std=[])
    # no rigid body, no count observer (it predicts with the body)
    cv_none["filter"] = {k: v for k, v in cv_none["filter"].items() if not k.startswith("count_")}
    return (model.to_dict(), wn.to_dict(), cv_none)


def _load_model(data: bytes) -> object:
    return DynamicModel.load(_scratch("model.json", data))


def _model_to_estimator(data: bytes) -> object:
    """What the service does with a model file it is asked to load (read, build, try)."""
    from teleop_force.errors import TeleopForceError
    from teleop_force.estimation.estimator import ForceEstimator

    model = DynamicModel.load(_scratch("model.json", data))
    estimator = ForceEstimator(model)
    q = np.full(model.n_joints, 0.3)
    try:
        for k in range(3):
            estimator.update(k * 1e-3, q, np.zeros(model.n_joints))
    except TeleopForceError:
        raise
    return estimator


def _model_seeds() -> list[bytes]:
    return [json.dumps(d).encode() for d in model_seed_dicts()]


# --------------------------------------------------------------------------- the table

_MODEL_ERRORS = (ModelFileError, ModelError, DataError)

#: Findings of this fuzzing not fixed yet, reported to the owners of the modules (see
#: docs/reliability.md): ``{"X1": KnownIssue("X1", TypeError, r"message", ("module.py",))}``.
#: R1 (robot_file) and M1-M4 (dynamic_model, regressor, friction from_dict) were fixed: the
#: tests in tests/robots/test_robot_file.py and tests/identification/test_dynamic_model_file.py
#: keep them fixed.
KNOWN_ISSUES: dict[str, KnownIssue] = {}

TARGETS: dict[str, Target] = {
    t.name: t
    for t in (
        Target("messages.decode", _decode_any, (MessageError,), _message_seeds),
        Target("Message classes .decode", _decode_each, (MessageError,), _message_seeds),
        Target("Message classes .from_json_dict", _from_json, (MessageError,), _message_json_seeds),
        Target("MCAP session reader", _read_mcap, (DataError,), lambda: list(_mcap_seed_bytes())),
        Target(
            "ROS 2 decoders (CDR, attachment, token)", _decode_ros2, (MessageError,), _ros2_seeds
        ),
        Target("interchange CSV", _read_csv, (DataError,), lambda: list(_csv_seed_bytes())),
        Target("robot description file", _read_robot, (ModelError, DataError), _robot_seeds),
        Target("model file (DynamicModel.load)", _load_model, _MODEL_ERRORS, _model_seeds),
    )
}


def model_to_estimator_target() -> Target:
    """Model file -> estimator -> 3 samples, as the service's run-time load does."""
    from teleop_force.errors import TeleopForceError

    return Target(
        "model file -> estimator (service load)",
        _model_to_estimator,
        (TeleopForceError,),
        _model_seeds,
    )


TARGETS["model file -> estimator (service load)"] = model_to_estimator_target()


def cleanup() -> None:
    """Remove the scratch folder (best effort)."""
    shutil.rmtree(_WORK, ignore_errors=True)


def random_mutation(rng: random.Random, data: bytes, max_ops: int = 4) -> bytes:
    """A byte-level mutation drawn with ``rng`` (for bulk inputs outside hypothesis)."""
    buf = bytearray(data)
    for _ in range(rng.randint(1, max_ops)):
        op = rng.choice(("flip", "set", "truncate", "insert", "delete"))
        if op == "truncate":
            del buf[rng.randint(0, len(buf)) :]
        elif op == "insert":
            i = rng.randint(0, len(buf))
            buf[i:i] = rng.randbytes(rng.randint(1, 16))
        elif buf:
            i = rng.randrange(len(buf))
            if op == "delete":
                del buf[i]
            elif op == "flip":
                buf[i] ^= 1 << rng.randrange(8)
            else:
                buf[i] = rng.randrange(256)
    return bytes(buf)


def fuzzed_payloads(n: int, seed: int = 0) -> list[bytes]:
    """``n`` payloads: mutated valid messages of every type, random bytes, and valid ones."""
    return _fuzzed(_message_seeds(), n, seed)


def _fuzzed(seeds: list[bytes], n: int, seed: int) -> list[bytes]:
    """``n`` payloads of ``seeds``: one in ten random bytes, one in ten a seed, the rest mutated."""
    rng = random.Random(seed)
    out = []
    for k in range(n):
        choice = k % 10
        if choice == 0:
            out.append(rng.randbytes(rng.randint(0, 120)))
        elif choice == 1:
            out.append(rng.choice(seeds))
        else:
            out.append(random_mutation(rng, rng.choice(seeds)))
    return out


def ros2_seeds() -> list[bytes]:
    """Valid CDR payloads of every live topic (3 and 9 joints), an attachment and a token."""
    from teleop_force.ros2 import codec

    nine = m.JointState(3, 1_700_000_000_000_000_000, tuple(np.linspace(-1, 1, 9)), (0.0,) * 9,
                        (1e-3,) * 9)  # fmt: skip
    return [*_ros2_seeds(), codec.encode_joint_state(nine, ()),
            codec.encode_joint_setpoint(m.JointSetpoint(1, 2, (0.1,) * 9), ())]  # fmt: skip


def fuzzed_ros2_payloads(n: int, seed: int = 0) -> list[bytes]:
    """``n`` payloads: mutated valid CDR messages of every topic, random bytes, valid ones."""
    return _fuzzed(ros2_seeds(), n, seed)


def count(target_name: str, outcome: str, n: int = 1) -> None:
    """Add ``n`` inputs with ``outcome`` to :data:`COUNTS` (for targets fed in bulk)."""
    with _LOCK:
        COUNTS.setdefault(target_name, Counter())[outcome] += n
