"""issue 29, item 2: no string from a file runs as script in a viewer page. Every text the page shows is HTML-
escaped (relight.view._page._esc), and the slider's data, JSON inside a <script> element, has ``<``, ``>``, ``&``
and U+2028 / U+2029 written as \\u escapes (``_script_json``): the HTML parser cannot end the element early, and
the data parse back to the same strings."""

import json
import re

import numpy as np

from relight.view import Sweep, page_html

HOSTILE = "</script><script>document.title='X'</script><!-- & \u2028\u2029 <img src=x onerror=alert(1)>"


def test_a_label_from_a_file_stays_data(tmp_path):
    (tmp_path / "settings.json").write_text(json.dumps({"command": HOSTILE}))
    frames = np.zeros((2, 4, 4, 3), np.uint8)
    page = page_html(tmp_path, sweeps=[Sweep(HOSTILE, np.array([0.0, 180.0]), frames, 0.0)], title=HOSTILE)
    # The page's own markup: its script elements are only the ones the page writes (the hook, the data, the
    # slider's code), and the hostile markup appears nowhere unescaped.
    assert "<script>document.title" not in page and "<img src=x" not in page and "<!-- &" not in page
    assert page.count("<script>") == 3, page.count("<script>")
    # The data parse back to the same label.
    m = re.search(r"<script>window\.SWEEPS=(.*?);</script>", page, re.S)
    assert m is not None and "</" not in m.group(1)
    assert json.loads(m.group(1))[0]["label"] == HOSTILE


def test_the_page_embeds_only_regular_files_inside_its_folder(tmp_path):
    """issue 29, item 3: what the page embeds is a regular file inside the folder once links are followed, of
    bounded size, of the type its name claims (relight.view._page._read_inside). A link to a file elsewhere, a
    device, a FIFO (which would block the read) and a PNG name on text are listed as not embedded, and
    report.md linked to a file outside is not shown."""
    import os

    from relight.io import write_png

    folder = tmp_path / "set"
    folder.mkdir()
    secret = tmp_path / "secret.txt"
    secret.write_text("root:x:0:0:SECRET-CONTENT")
    write_png(folder / "ok.png", np.full((4, 4, 3), 128, np.uint8))
    (folder / "leak.png").symlink_to(secret)
    (folder / "zero.png").symlink_to("/dev/zero")
    os.mkfifo(folder / "fifo.png")
    (folder / "text.png").write_text("not a png")
    (folder / "report.md").symlink_to(secret)
    page = page_html(folder)
    assert "SECRET" not in page and "cm9vdDp4" not in page  # the secret, and its base64
    assert "ok.png" in page and page.count("data:image/png;base64,") >= 1
    for name, why in (("leak.png", "a link to outside the folder"), ("zero.png", "a link to outside the folder"),
                      ("fifo.png", "not a regular file"), ("text.png", "not the type its name says")):
        assert f"{name} ({why})" in page, name
    assert "report.md not shown: a link to outside the folder" in page
