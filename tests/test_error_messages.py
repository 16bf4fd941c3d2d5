"""One clear message per error: a failing rule script prints one line on stderr and keeps the
traceback in its log file; a config file that is not YAML is named with its line."""

import re
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from granular_multiscale.config import ConfigError, read_config_file
from granular_multiscale.runlog import setup_logging, timed_rule

ROOT = Path(__file__).resolve().parents[1]
SNAKEMAKE = str(Path(sys.executable).with_name("snakemake"))

FAILING_SCRIPT = """\
from granular_multiscale.runlog import setup_logging, timed_rule
logger = setup_logging({log!r})
with timed_rule(logger, "fem_ml path2"):
    raise ValueError("step 3 did not converge")
"""


def run_python(code: str, tmp_path: Path) -> subprocess.CompletedProcess:
    script = tmp_path / "script.py"
    script.write_text(code)
    return subprocess.run([sys.executable, str(script)], capture_output=True, text=True, timeout=60)


def test_a_failing_rule_script_prints_one_line_and_logs_the_traceback(tmp_path):
    log = tmp_path / "logs" / "fem_ml.log"
    result = run_python(FAILING_SCRIPT.format(log=str(log)), tmp_path)
    assert result.returncode == 1
    assert "Traceback" not in result.stderr
    failures = [line for line in result.stderr.splitlines() if "failed" in line]
    assert len(failures) == 1, result.stderr
    assert re.search(rf"fem_ml path2 failed after \d+\.\d s: ValueError: step 3 did not converge "
                     rf"\(full traceback: {re.escape(str(log))}\)$", failures[0]), failures[0]
    text = log.read_text()
    assert "Traceback (most recent call last)" in text and 'raise ValueError("step 3 did not converge")' in text


def test_an_exception_outside_timed_rule_keeps_its_traceback(tmp_path):
    code = f"from granular_multiscale.runlog import setup_logging\nsetup_logging({str(tmp_path / 'x.log')!r})\n1 / 0\n"
    result = run_python(code, tmp_path)
    assert result.returncode == 1 and "Traceback" in result.stderr and "ZeroDivisionError" in result.stderr


def test_the_exception_still_reaches_a_caller(tmp_path, monkeypatch, capsys):
    """Tests call the scripts' main() directly and expect the exception itself."""
    monkeypatch.setattr(sys, "excepthook", sys.excepthook)  # setup_logging sets it; restored after
    logger = setup_logging(tmp_path / "rule.log")
    with pytest.raises(KeyError, match="sigma"):
        with timed_rule(logger, "train"):
            raise KeyError("sigma")
    assert "Traceback" not in capsys.readouterr().err
    assert "Traceback" in (tmp_path / "rule.log").read_text()


def test_a_failing_script_rule_under_snakemake_prints_no_python_traceback(tmp_path):
    """The same through Snakemake's `script:` (a subprocess whose exit status fails the job)."""
    (tmp_path / "fail.py").write_text(FAILING_SCRIPT.replace("{log!r}", "snakemake.log[0]"))
    (tmp_path / "Snakefile").write_text(textwrap.dedent("""\
        rule fail:
            output: "out.txt"
            log: "logs/fail.log"
            script: "fail.py"
        """))
    result = subprocess.run([SNAKEMAKE, "-j1", "-q"], cwd=tmp_path, capture_output=True, text=True, timeout=300)
    output = result.stdout + result.stderr
    assert result.returncode != 0
    assert output.count("ValueError: step 3 did not converge") == 1, output
    assert f"(full traceback: {tmp_path / 'logs' / 'fail.log'})" in output
    assert "Traceback" not in output


# -- config files that are not YAML ---------------------------------------------------------
@pytest.mark.parametrize(
    "text, where",
    [
        ("specimen: {elements: [1, 1, 2]\n", "(line 2, column 1)"),
        ("dem:\n  n_spheres: 100\n\tfriction: 0.3\n", "(line 3, column 1)"),
        ("dem:\n  n_spheres: 100\n friction: 0.3\n", "(line 3, column 2)"),
    ],
)
def test_a_config_file_that_is_not_yaml_is_named_with_its_line(tmp_path, text, where):
    path = tmp_path / "broken.yaml"
    path.write_text(text)
    with pytest.raises(ConfigError) as error:
        read_config_file(path)
    message = str(error.value)
    assert message.startswith(f"config file {path} is not valid YAML {where}: ") and "\n" not in message


def test_a_missing_config_file_is_named(tmp_path):
    with pytest.raises(ConfigError, match=r"config file not found: .*nope\.yaml"):
        read_config_file(tmp_path / "nope.yaml")


@pytest.mark.parametrize("text", ["- 1\n- 2\n", "just a string\n"])
def test_a_config_file_without_keys_is_named(tmp_path, text):
    path = tmp_path / "list.yaml"
    path.write_text(text)
    with pytest.raises(ConfigError, match=r"list\.yaml: the top level must be a mapping"):
        read_config_file(path)


def test_snakemake_names_the_line_of_a_broken_default_config(tmp_path):
    """The Snakefile's own config/config.yaml (relative to the working directory, here a copy
    with an unclosed mapping): one line naming file and line, no traceback."""
    (tmp_path / "config").mkdir()
    text = (ROOT / "config" / "config.yaml").read_text() + "dem: {n_spheres: 100\n"
    (tmp_path / "config" / "config.yaml").write_text(text)
    result = subprocess.run([SNAKEMAKE, "-n", "-s", str(ROOT / "Snakefile"), "-d", str(tmp_path)], cwd=ROOT,
                            capture_output=True, text=True, timeout=300)
    output = result.stdout + result.stderr
    line = len(text.splitlines()) + 1
    assert result.returncode != 0
    assert f"Configuration error: config file config/config.yaml is not valid YAML (line {line}, column 1)" in output
    assert "Traceback" not in output
