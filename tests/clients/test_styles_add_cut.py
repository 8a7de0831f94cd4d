"""``rsmt client styles add FILE --start S --frames N``: a part of a longer take becomes the style clip."""

from __future__ import annotations

import json

from rsmt_client.bvh import BvhFile

from rsmt_cli.main import main
from tests.clients.helpers import API_KEY


def test_a_cut_of_a_take_is_registered_as_that_cut(server, motions, capsys) -> None:
    common = ["--url", server.url, "--api-key", API_KEY]
    take = motions["style"]  # 120 frames at 30 fps
    assert main(["client", "styles", "add", str(take), "--start", "30", "--frames", "60", "--name", "middle", *common]) == 0
    cut = json.loads(capsys.readouterr().out)
    assert cut["frames"] == 60 and cut["name"] == "middle"
    # The same frames written to a file of their own register as the same clip (same content-hash id).
    part = motions["style"].parent / "middle.bvh"
    BvhFile.read(take).window(30, 60).write(part, precision=None)
    assert main(["client", "styles", "add", str(part), *common]) == 0
    assert json.loads(capsys.readouterr().out)["style_id"] == cut["style_id"]
    assert main(["client", "styles", "add", str(take), *common]) == 0
    assert json.loads(capsys.readouterr().out)["style_id"] != cut["style_id"]


def test_a_cut_outside_the_take_is_refused_before_any_request(motions, capsys) -> None:
    take = motions["style"]
    # No server at this URL: the range is checked first, so the error is the range, not the connection.
    args = ["client", "styles", "add", str(take), "--url", "http://127.0.0.1:9", "--retries", "1"]
    assert main([*args, "--start", "100", "--frames", "40"]) == 2
    err = capsys.readouterr().err
    assert "frames 100 to 139 are outside the file's 120 frames (0 to 119, at 30 fps)" in err, err
    assert main([*args, "--start", "-1"]) == 2
    assert "outside the file's 120 frames" in capsys.readouterr().err
    assert main([*args, "--start", "0", "--frames", "0"]) == 2
