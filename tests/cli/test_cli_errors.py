"""How the command line reports errors: one plain paragraph, the right exit status, never a traceback."""

from __future__ import annotations


import pytest


def test_an_unexpected_error_is_one_paragraph_exit_1(monkeypatch, run_cli):
    import jcalib.io.export as export

    def boom(*a, **k):
        raise RuntimeError("something [/x] broke\x1b[2J")

    monkeypatch.setattr(export, "export_result", boom)
    code, text = run_cli("export", "r.json", "-f", "krl", "-o", "/tmp/jcalib-cli-errors.dat")
    assert code == 1 and "internal error" in text and "RuntimeError: something [/x] broke" in text
    assert "Traceback" not in text and "\x1b" not in text and text.count("\n") <= 2


def test_jcalib_debug_shows_the_traceback(monkeypatch, run_cli):
    import jcalib.io.export as export

    monkeypatch.setattr(export, "export_result", lambda *a, **k: 1 / 0)
    monkeypatch.setenv("JCALIB_DEBUG", "1")
    with pytest.raises(ZeroDivisionError):
        run_cli("export", "r.json", "-f", "krl", "-o", "/tmp/jcalib-cli-errors.dat")


@pytest.mark.parametrize("message", ["a [/x] b", "[bold]x[/bold]", "newline\nbell\x07 esc\x1b[31m"])
def test_error_messages_are_printed_verbatim_without_markup(monkeypatch, message, run_cli):
    import jcalib.io.export as export
    from jcalib.errors import BadInputError

    def bad(*a, **k):
        raise BadInputError(message)

    monkeypatch.setattr(export, "export_result", bad)
    code, text = run_cli("export", "r.json", "-f", "krl", "-o", "/tmp/jcalib-cli-errors.dat")
    assert code == 2 and text.startswith("jcalib error: ")
    shown = text[len("jcalib error: "):].rstrip("\n")
    assert shown == message.replace("\x07", "\\x07").replace("\x1b", "\\x1b")


def test_export_options_of_another_format_are_refused(tmp_path, run_cli):
    code, text = run_cli("export", "r.json", "-f", "krl", "--camera", "cam0", "-o", tmp_path / "o.dat")
    assert code == 2 and "--camera applies to the opencv and ros formats" in text
    code, text = run_cli("export", "r.json", "-f", "opencv", "--module", "m", "-o", tmp_path / "o.yaml")
    assert code == 2 and "--module applies to the rapid format" in text
