import shlex
import sys

from jaxcls import report


def test_command_line_is_retypeable(monkeypatch):
    monkeypatch.setattr(sys, "argv", ["benchmarks/x.py", "ignored"])
    line = report.command_line(["--out", "B.md", "scene.split=all", "a b"])
    assert shlex.split(line) == ["python", "benchmarks/x.py", "--out", "B.md", "scene.split=all", "a b"]


def test_publish_appends_sections(tmp_path, capsys):
    out = tmp_path / "R.md"
    out.write_text("# R\n")
    report.publish("| a |\n", out)
    report.publish("| b |\n", out)
    assert out.read_text() == "# R\n\n| a |\n\n| b |\n"
    assert "| b |" in capsys.readouterr().out


def test_section_is_a_markdown_table_with_its_command(monkeypatch):
    monkeypatch.setattr(sys, "argv", ["experiments/x.py"])
    text = report.section("Title", ["--n", "3"], ("a", "b"), [(1, "x"), ("all", 2.5)], intro="Intro.",
                          notes=["skipped y"])
    assert text == ("### Title\n\n`python experiments/x.py --n 3`\n\nIntro.\n\n| a | b |\n| --- | --- |\n"
                    "| 1 | x |\n| all | 2.5 |\n\n- skipped y\n")


def test_process_age_counts_from_the_process_start():
    """``report.process_age``: a process that slept 1.5 s before asking is at least that old (Linux's /proc;
    None elsewhere)."""
    import subprocess

    code = "import time; time.sleep(1.5); from jaxcls import report; print(report.process_age())"
    age = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout.strip()
    if not sys.platform.startswith("linux"):
        assert age == "None"
        return
    assert 1.5 <= float(age) < 30


def test_interleaved_runs_the_contenders_round_robin():
    calls = []
    contenders = {"a": lambda: calls.append("a") or len(calls), "b": lambda: calls.append("b") or len(calls)}
    times, results = report.interleaved(contenders, 3)
    assert calls == ["a", "b"] * 3 and results == {"a": 5, "b": 6}
    assert [len(t) for t in times.values()] == [3, 3] and all(x >= 0 for t in times.values() for x in t)
