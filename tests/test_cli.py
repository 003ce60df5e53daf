"""The command line: where a newcomer starts, and --data-dir wherever it is written."""

from __future__ import annotations

import pytest

from app.cli import build_parser, main


def test_help_says_where_to_start(capsys):
    with pytest.raises(SystemExit):
        main(["--help"])
    text = capsys.readouterr().out
    assert text.index("conforma demo") < text.index("conforma serve")


@pytest.mark.parametrize("order", ["after", "before"])
def test_keys_take_the_data_dir_before_or_after_the_subcommand(tmp_path, capsys, order):
    where = ["--data-dir", str(tmp_path)]
    create = ["keys", *where, "create", "--role", "viewer", "--name", "lab"] if order == "before" \
        else ["keys", "create", "--role", "viewer", "--name", "lab", *where]
    assert main(create) == 0
    key_id = capsys.readouterr().out.split()[0]
    listing = ["keys", "list", *where] if order == "after" else ["keys", *where, "list"]
    assert main(listing) == 0
    assert key_id in capsys.readouterr().out
    assert (tmp_path / "conforma.db").exists() or any(tmp_path.iterdir())
    assert build_parser().parse_args(["keys", "list", *where]).data_dir == tmp_path
