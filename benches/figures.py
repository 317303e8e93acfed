"""What the figure scripts (readme-figures.sh, performance-figures.sh) share."""


def splice(path, marker, figures):
    """Replaces what `path` holds between `<!-- MARKER:begin -->` and
    `<!-- MARKER:end -->` with `figures`."""
    text = open(path).read()
    a, b = f"<!-- {marker}:begin -->\n", f"<!-- {marker}:end -->"
    i, j = text.index(a) + len(a), text.index(b)
    open(path, "w").write(text[:i] + figures + text[j:])
