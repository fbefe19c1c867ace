"""``pwl fleet score`` on diagnoses that are not one clean 0/1 row per engine and flight: engines or
flights missing (counted as not detected, and named), booleans spelled True/yes, flight names
instead of numbers, repeated rows, engines the truth does not know. Every expected figure is counted
by hand from the small fleet below: 4 engines x 10 flights, E1 hpt from flight 5, E2 sensor:T48
from flight 5, E3 healthy, E4 hpc from flight 5."""
import csv

import pytest

from pwl.cli import main
from pwl.errors import EXIT_INPUT, PwlError
from pwl.fleet.scoring import ScoreError, score, table

TRUTH = [["E1", "hpt", -0.02, "fraction", "", 5], ["E2", "sensor:T48", 4.0, "sigma", 30.0, 5],
         ["E3", "none", 0.0, "", "", -1], ["E4", "hpc", -0.03, "fraction", "", 5]]
HEADER = ["engine", "flight", "detected", "class", "magnitude", "bias"]
ONSET = {"E1": 5, "E2": 5, "E3": None, "E4": 5}
CLASS = {"E1": "hpt", "E2": "sensor:T48", "E3": "none", "E4": "hpc"}


def write_csv(path, header, rows):
    with open(path, "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(header)
        w.writerows(rows)
    return path


def perfect_rows(engines=("E1", "E2", "E3", "E4"), flights=range(10), yes="1", no="0"):
    """A diagnosis that detects and classifies every fault from its onset on, nothing else."""
    rows = []
    for e in engines:
        for k in flights:
            on = ONSET[e] is not None and k >= ONSET[e]
            rows.append([e, k, yes if on else no, CLASS[e] if on else "none", "", ""])
    return rows


@pytest.fixture
def truth(tmp_path):
    return write_csv(tmp_path / "truth.csv", ["engine", "class", "magnitude", "unit", "bias", "onset"], TRUTH)


def test_perfect_diagnosis_scores_perfect_without_notes(tmp_path, truth):
    r = score(write_csv(tmp_path / "d.csv", HEADER, perfect_rows()), truth)
    assert (r["engines"], r["engine_flights"], r["fault_flights"]) == (4, 40, 15)
    assert r["tpr"] == 1.0 and r["fpr"] == 0.0 and r["notes"] == []
    assert r["missing_engines"] == [] and r["missing_engine_flights"] == 0


def test_engine_missing_from_diagnosis_counts_as_not_detected(tmp_path, truth):
    rows = [r for r in perfect_rows() if r[0] != "E4"]
    r = score(write_csv(tmp_path / "d.csv", HEADER, rows), truth)
    # E4's 10 flights are scored as not detected: 5 of them fault-present (5..9), 5 without
    assert r["engines"] == 4 and r["engine_flights"] == 40
    assert r["fault_flights"] == 15 and r["tpr"] == pytest.approx(10 / 15)
    assert r["no_fault_flights"] == 25 and r["fpr"] == 0.0
    assert r["missing_engines"] == ["E4"] and r["missing_engine_flights"] == 10
    assert "E4" in r["undetected"] and r["per_class"]["hpc"]["engines"] == 1
    text = table(r)
    assert "1 engine of the truth not in the diagnosis" in text and "E4" in text


def test_flights_missing_from_one_engine_count_as_not_detected(tmp_path, truth):
    rows = [r for r in perfect_rows() if not (r[0] == "E4" and r[1] >= 5)]   # E4: flights 0..4 only
    r = score(write_csv(tmp_path / "d.csv", HEADER, rows), truth)
    assert r["engine_flights"] == 40 and r["fault_flights"] == 15 and r["tpr"] == pytest.approx(10 / 15)
    assert r["missing_engines"] == [] and r["missing_engine_flights"] == 5
    assert "E4 (5: flights 5-9)" in table(r)


@pytest.mark.parametrize("yes,no", [("True", "False"), ("true", "false"), ("yes", "no"),
                                    ("YES", "No"), ("1", "0"), ("1.0", "0.0")])
def test_detected_in_any_common_spelling(tmp_path, truth, yes, no):
    r = score(write_csv(tmp_path / "d.csv", HEADER, perfect_rows(yes=yes, no=no)), truth)
    assert r["tpr"] == 1.0 and r["fpr"] == 0.0 and r["correct_classification"] == 1.0


@pytest.mark.parametrize("value", ["", "2", "detected", "maybe"])
def test_detected_unreadable_is_refused_naming_column_line_and_value(tmp_path, truth, value):
    rows = perfect_rows()
    rows[6][2] = value                                     # E1 flight 6: line 8 of the file
    d = write_csv(tmp_path / "d.csv", HEADER, rows)
    with pytest.raises(ScoreError, match=rf"line 8: column 'detected' is '{value}'"):
        score(d, truth)


def test_flight_names_are_refused_naming_the_value(tmp_path, truth):
    rows = [[e, f"flight_{k:03d}", *rest] for e, k, *rest in perfect_rows()]
    d = write_csv(tmp_path / "d.csv", HEADER, rows)
    with pytest.raises(ScoreError, match=r"line 2: column 'flight' is 'flight_000'"):
        score(d, truth)


def test_identical_repeated_rows_count_once_with_a_note(tmp_path, truth):
    rows = perfect_rows()
    rows += [list(r) for r in rows if r[0] == "E1"]      # E1's 10 rows written twice
    r = score(write_csv(tmp_path / "d.csv", HEADER, rows), truth)
    assert r["engine_flights"] == 40 and r["fault_flights"] == 15 and r["repeated_rows"] == 10
    assert "10 rows repeat an earlier row" in table(r)


def test_conflicting_repeated_rows_are_refused_naming_the_first(tmp_path, truth):
    rows = perfect_rows()
    rows.append(["E2", 7, "0", "none", "", ""])           # line 42: E2 flight 7 again, now not detected
    rows.append(["E3", 1, "1", "fan", "", ""])
    d = write_csv(tmp_path / "d.csv", HEADER, rows)
    with pytest.raises(ScoreError, match=r"line 42: engine E2 flight 7 is already on line 19"):
        score(d, truth)


def test_engines_not_in_the_truth_are_refused_counted_and_named(tmp_path, truth):
    rows = perfect_rows() + [[f"X{i}", 0, "0", "none", "", ""] for i in range(7)]
    d = write_csv(tmp_path / "d.csv", HEADER, rows)
    with pytest.raises(ScoreError, match=r"7 engines are not in .*truth.csv: X0, X1, X2, X3, X4, \.\.\."):
        score(d, truth)


def test_truth_onset_unreadable_is_refused(tmp_path):
    t = write_csv(tmp_path / "truth.csv", ["engine", "class", "onset"], [["E1", "hpt", "five"]])
    d = write_csv(tmp_path / "d.csv", HEADER, [["E1", 0, "0", "none", "", ""]])
    with pytest.raises(ScoreError, match=r"truth.csv: line 2: column 'onset' is 'five'"):
        score(d, t)


def test_cli_refuses_with_exit_2_and_prints_notes(tmp_path, truth, capsys):
    rows = perfect_rows(yes="maybe")
    bad = write_csv(tmp_path / "bad.csv", HEADER, rows)
    assert main(["fleet", "score", str(bad), str(truth)]) == EXIT_INPUT
    err = capsys.readouterr().err
    assert "column 'detected' is 'maybe'" in err and "Traceback" not in err
    ok = write_csv(tmp_path / "ok.csv", HEADER, [r for r in perfect_rows() if r[0] != "E4"])
    assert main(["fleet", "score", str(ok), str(truth)]) == 0
    out = capsys.readouterr().out
    assert out.startswith("4 engines, 40 engine-flights") and "not in the diagnosis" in out
    assert issubclass(ScoreError, PwlError)
