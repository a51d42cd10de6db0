import teleop_force
from teleop_force import errors


def test_all_is_sorted_and_importable() -> None:
    assert teleop_force.__all__ == sorted(teleop_force.__all__)
    for name in teleop_force.__all__:
        assert getattr(teleop_force, name) is not None


def test_every_error_is_a_teleop_force_error_and_a_builtin() -> None:
    for name in (
        "DataError",
        "ModelError",
        "ModelFileError",
        "MessageError",
        "TransportError",
        "SingularityError",
        "ConfigurationError",
    ):
        cls = getattr(errors, name)
        assert issubclass(cls, errors.TeleopForceError)
        assert any(issubclass(cls, b) for b in (ValueError, ConnectionError, ArithmeticError))
