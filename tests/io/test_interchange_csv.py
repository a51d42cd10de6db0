import numpy as np
import pytest

from teleop_force.errors import DataError
from teleop_force.io.interchange_csv import (
    Recording,
    header_columns,
    read_interchange_csv,
    write_interchange_csv,
)


def make_recording(n_samples=50, n_joints=3, with_force=True, seed=0):
    rng = np.random.default_rng(seed)
    t = np.cumsum(rng.uniform(0.5e-3, 1.5e-3, n_samples))
    f = rng.normal(size=(n_samples, 3)) if with_force else None
    return Recording(
        t, rng.normal(size=(n_samples, n_joints)), rng.normal(size=(n_samples, n_joints)), f
    )


def write_text(tmp_path, text, name="rec.csv"):
    path = tmp_path / name
    path.write_text(text, encoding="utf-8")
    return path


def error_of(path, **kwargs) -> DataError:
    with pytest.raises(DataError) as info:
        read_interchange_csv(path, **kwargs)
    err = info.value
    assert str(path) in str(err)  # the one line names the file
    assert "\n" not in str(err)
    return err


GOOD = "t,q1,q2,tau1,tau2\n0.0,1,2,3,4\n0.001,1,2,3,4\n0.002,1,2,3,4\n"


# ------------------------------------------------------------------------------ round trip


@pytest.mark.parametrize(("n_joints", "with_force"), [(3, True), (3, False), (2, True), (6, False)])
def test_round_trip_is_exact(tmp_path, n_joints, with_force):
    rec = make_recording(n_joints=n_joints, with_force=with_force)
    path = tmp_path / "r.csv"
    write_interchange_csv(path, rec)
    back = read_interchange_csv(path)
    assert back.n_joints == n_joints
    assert back.has_force == with_force
    assert back.source == path
    np.testing.assert_array_equal(back.t_s, rec.t_s)
    np.testing.assert_array_equal(back.q_rad, rec.q_rad)
    np.testing.assert_array_equal(back.tau_nm, rec.tau_nm)
    if with_force:
        np.testing.assert_array_equal(back.f_tip_in_base_n, rec.f_tip_in_base_n)
    assert path.read_text().splitlines()[0] == ",".join(header_columns(n_joints, with_force))
    assert not list(tmp_path.glob(".*tmp"))  # the atomic write left no temporary file


def test_extra_columns_and_column_order(tmp_path):
    path = write_text(
        tmp_path,
        "label,tau2,q2,T,q1,tau1,f_z,f_y,f_x\nrun_1,4,2,0.5,1,3,9,8,7\nrun_1,40,20,0.6,10,30,90,80,70\n",
    )
    rec = read_interchange_csv(path)
    np.testing.assert_array_equal(rec.t_s, [0.5, 0.6])
    np.testing.assert_array_equal(rec.q_rad, [[1, 2], [10, 20]])
    np.testing.assert_array_equal(rec.tau_nm, [[3, 4], [30, 40]])
    np.testing.assert_array_equal(rec.f_tip_in_base_n, [[7, 8, 9], [70, 80, 90]])


def test_explicit_joint_count_ignores_further_joints(tmp_path):
    path = write_text(tmp_path, "t,q1,q2,q3,tau1,tau2,tau3\n0,1,2,3,4,5,6\n1,1,2,3,4,5,6\n")
    rec = read_interchange_csv(path, n_joints=2)
    np.testing.assert_array_equal(rec.q_rad, [[1, 2], [1, 2]])
    np.testing.assert_array_equal(rec.tau_nm, [[4, 5], [4, 5]])


def test_crlf_bom_whitespace_and_trailing_blank_lines(tmp_path):
    path = tmp_path / "win.csv"
    path.write_bytes(b"\xef\xbb\xbft, q1 ,tau1\r\n0, 1.5 ,2\r\n1e-3,+3,-.5\r\n\r\n\r\n")
    rec = read_interchange_csv(path)
    np.testing.assert_array_equal(rec.q_rad[:, 0], [1.5, 3.0])
    np.testing.assert_array_equal(rec.tau_nm[:, 0], [2.0, -0.5])


def test_recording_arrays_are_read_only_copies():
    t = np.array([0.0, 1.0])
    rec = Recording(t, [[1.0], [2.0]], [[3.0], [4.0]])
    t[0] = 5.0
    assert rec.t_s[0] == 0.0
    with pytest.raises(ValueError):
        rec.q_rad[0, 0] = 1.0
    assert len(rec) == 2 and rec.n_samples == 2 and rec.n_joints == 1 and not rec.has_force


# ------------------------------------------------------------------------------ bad input


def test_missing_column(tmp_path):
    err = error_of(write_text(tmp_path, "t,q1,q2,tau1\n0,1,2,3\n"))
    assert (err.row, err.column) == (1, "tau2")
    assert "missing column" in err.problem


def test_missing_time_column(tmp_path):
    err = error_of(write_text(tmp_path, "time,q1,tau1\n0,1,2\n"))
    assert (err.row, err.column) == (1, "t")


def test_missing_joint_columns_entirely(tmp_path):
    err = error_of(write_text(tmp_path, "t,x\n0,1\n"))
    assert (err.row, err.column) == (1, "q1")


def test_partial_force_columns(tmp_path):
    err = error_of(write_text(tmp_path, "t,q1,tau1,f_x,f_z\n0,1,2,3,4\n"))
    assert (err.row, err.column) == (1, "f_y")


def test_requested_joint_count_missing(tmp_path):
    err = error_of(write_text(tmp_path, GOOD), n_joints=3)
    assert (err.row, err.column) == (1, "q3")


def test_duplicate_column(tmp_path):
    err = error_of(write_text(tmp_path, "t,q1,tau1,q1\n0,1,2,3\n"))
    assert (err.row, err.column) == (1, "q1")
    assert "duplicate" in err.problem


def test_non_numeric_cell(tmp_path):
    err = error_of(write_text(tmp_path, GOOD.replace("0.001,1,2,3,4", "0.001,1,abc,3,4")))
    assert (err.row, err.column) == (3, "q2")
    assert "'abc'" in err.problem


@pytest.mark.parametrize("cell", ["1_000", "0x10", "1.0e", "١"])
def test_numbers_python_would_accept_but_the_format_does_not(tmp_path, cell):
    err = error_of(write_text(tmp_path, GOOD.replace("0.002,1,2,3,4", f"0.002,1,2,{cell},4")))
    assert (err.row, err.column) == (4, "tau1")


def test_empty_cell(tmp_path):
    err = error_of(write_text(tmp_path, GOOD.replace("0.002,1,2,3,4", "0.002,1,2,3,")))
    assert (err.row, err.column) == (4, "tau2")
    assert "empty cell" in err.problem


@pytest.mark.parametrize("cell", ["nan", "NaN", "inf", "-inf", "Infinity"])
def test_non_finite_value(tmp_path, cell):
    err = error_of(write_text(tmp_path, GOOD.replace("0.002,1,2,3,4", f"0.002,1,2,{cell},4")))
    assert (err.row, err.column) == (4, "tau1")
    assert "not finite" in err.problem


def test_non_increasing_time(tmp_path):
    text = "t,q1,tau1\n0.000,0,0\n0.001,0,0\n0.002,0,0\n0.0015,0,0\n"
    err = error_of(write_text(tmp_path, text))
    assert (err.row, err.column) == (5, "t")
    assert "not strictly increasing" in err.problem


def test_repeated_time(tmp_path):
    err = error_of(write_text(tmp_path, "t,q1,tau1\n0,0,0\n1,0,0\n1,0,0\n"))
    assert (err.row, err.column) == (4, "t")


@pytest.mark.parametrize("content", [b"", b"\n\n", b"   \r\n"])
def test_empty_file(tmp_path, content):
    path = tmp_path / "empty.csv"
    path.write_bytes(content)
    err = error_of(path)
    assert err.row == 1
    assert "empty file" in err.problem


def test_no_data_rows(tmp_path):
    err = error_of(write_text(tmp_path, "t,q1,q2,tau1,tau2\n"))
    assert err.row == 2
    assert "no data rows" in err.problem


def test_ragged_row_too_short(tmp_path):
    err = error_of(write_text(tmp_path, GOOD.replace("0.001,1,2,3,4", "0.001,1,2,3")))
    assert err.row == 3
    assert "ragged row: 4 cells, the header has 5" in err.problem


def test_ragged_row_too_long(tmp_path):
    err = error_of(write_text(tmp_path, GOOD.replace("0.002,1,2,3,4", "0.002,1,2,3,4,5")))
    assert err.row == 4
    assert "ragged" in err.problem


def test_blank_line_between_rows(tmp_path):
    err = error_of(write_text(tmp_path, GOOD.replace("0.001,1,2,3,4\n", "0.001,1,2,3,4\n\n")))
    assert err.row == 4
    assert "empty row" in err.problem


def test_not_utf8(tmp_path):
    path = tmp_path / "latin.csv"
    path.write_bytes(b"t,q1,tau1\n0,1,2\n1,\xe9,2\n")
    err = error_of(path)
    assert err.row == 3
    assert "UTF-8" in err.problem


def test_missing_file_and_directory(tmp_path):
    assert "cannot read" in error_of(tmp_path / "nope.csv").problem
    assert "directory" in error_of(tmp_path).problem


def test_error_is_located_far_into_a_long_file(tmp_path):
    rec = make_recording(n_samples=5000, with_force=False)
    path = tmp_path / "long.csv"
    write_interchange_csv(path, rec)
    lines = path.read_text().splitlines()
    lines[4321] = lines[4321].rsplit(",", 1)[0] + ",oops"
    path.write_text("\n".join(lines) + "\n")
    err = error_of(path)
    assert (err.row, err.column) == (4322, "tau3")


@pytest.mark.parametrize(
    ("kwargs", "problem"),
    [
        ({"t_s": [0.0, 1.0], "q_rad": [[0.0]], "tau_nm": [[0.0]]}, "q_rad must have shape"),
        ({"t_s": [0.0, 1.0], "q_rad": [[0.0], [0.0]], "tau_nm": [[0.0]]}, "tau_nm"),
        ({"t_s": [], "q_rad": [], "tau_nm": []}, "no samples"),
        ({"t_s": [0.0, 0.0], "q_rad": [[0.0]] * 2, "tau_nm": [[0.0]] * 2}, "increasing"),
        ({"t_s": [0.0, 1.0], "q_rad": [[0.0], [np.nan]], "tau_nm": [[0.0]] * 2}, "finite"),
        (
            {"t_s": [0.0], "q_rad": [[0.0]], "tau_nm": [[0.0]], "f_tip_in_base_n": [[0.0]]},
            "f_tip_in_base_n",
        ),
        ({"t_s": ["a"], "q_rad": [[0.0]], "tau_nm": [[0.0]]}, "numeric"),
    ],
)
def test_recording_validation(kwargs, problem):
    with pytest.raises(DataError, match=problem):
        Recording(**kwargs)


@pytest.mark.slow
def test_240k_rows_round_trip(tmp_path):
    # a 4-minute 1 kHz recording (its speed is the bench's business, not a test's)
    rec = make_recording(n_samples=240_000, with_force=True)
    path = tmp_path / "big.csv"
    write_interchange_csv(path, rec)
    back = read_interchange_csv(path)
    assert back.n_samples == 240_000
    np.testing.assert_array_equal(back.t_s, rec.t_s)
    np.testing.assert_array_equal(back.q_rad, rec.q_rad)
    np.testing.assert_array_equal(back.tau_nm, rec.tau_nm)


def _cells_as_floats(text):
    """Each data cell parsed by Python's float(), which rounds decimal text correctly."""
    rows = text.rstrip("\n").split("\n")[1:]
    return np.array([[float(c) for c in row.split(",")] for row in rows])


def test_many_digit_cells_read_bit_exact(tmp_path):
    rng = np.random.default_rng(7)
    n_rows = 400
    cells = []
    for i in range(n_rows):
        t = f"{i}.{rng.integers(10**17, 10**18)}e-3"  # 18+ digits, more than a float holds
        digits = [
            f"{rng.normal():.40f}",
            f"{rng.normal() * 1e-300:.25e}",
            str(int(rng.integers(0, 2**62)) * 10**12),  # big integer, not exact in float64
            f"-{rng.uniform():.17g}E+{int(rng.integers(0, 300))}",
        ]
        cells.append(",".join([t, *digits]))
    text = "t,q1,q2,tau1,tau2\n" + "\n".join(cells) + "\n"
    expected = _cells_as_floats(text)
    rec = read_interchange_csv(write_text(tmp_path, text))
    got = np.column_stack([rec.t_s, rec.q_rad, rec.tau_nm])
    assert got.tobytes() == expected.tobytes()


def test_cells_json_rejects_still_parse_like_loadtxt(tmp_path):
    # "+1", "1.", ".5", "1e5", " 2 " and "007" are not JSON numbers: the slow path reads them.
    text = "t,q1,tau1,extra\n0.0,+1,1.,x\n.5, 2 ,007,y\n1e5,-0,3,z\n"
    rec = read_interchange_csv(write_text(tmp_path, text))
    np.testing.assert_array_equal(rec.t_s, [0.0, 0.5, 1e5])
    np.testing.assert_array_equal(rec.q_rad[:, 0], [1.0, 2.0, -0.0])
    np.testing.assert_array_equal(rec.tau_nm[:, 0], [1.0, 7.0, 3.0])


def test_bad_cell_after_many_good_rows_is_located(tmp_path):
    rows = [f"{i * 1e-3!r},1.5,2.5" for i in range(2000)]
    rows[1500] = f"{1500 * 1e-3!r},1.5,abc"
    path = write_text(tmp_path, "t,q1,tau1\n" + "\n".join(rows) + "\n")
    err = error_of(path)
    assert "row 1502" in str(err)
    assert "tau1" in str(err)
    assert "'abc'" in str(err)


def test_out_of_range_cell_reported_not_finite(tmp_path):
    path = write_text(tmp_path, "t,q1,tau1\n0.0,1,2\n0.001,1e400,2\n")
    err = error_of(path)
    assert "row 3" in str(err)
    assert "q1" in str(err)
