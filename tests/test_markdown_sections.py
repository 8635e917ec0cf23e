"""Generated sections replace only their own part of a markdown page."""

from mmcsplat.outputs.markdown_sections import replace_section


def test_sections_are_replaced_in_place_and_others_kept(tmp_path):
    page = tmp_path / "performance.md"
    replace_section(page, "bench", "| a | b |", "# Performance")
    replace_section(page, "dynamics", "per frame: 1 s", "# Performance")
    text = page.read_text()
    assert text.startswith("# Performance\n") and "| a | b |" in text and "per frame: 1 s" in text
    page.write_text(text + "\nA hand-written note.\n")
    replace_section(page, "bench", "| c | d |", "# Performance")
    text = page.read_text()
    assert "| a | b |" not in text and "| c | d |" in text
    assert "per frame: 1 s" in text and "A hand-written note." in text
    assert text.index("| c | d |") < text.index("per frame: 1 s")
