"""The documentation holds together: every relative link of the README and docs/ leads to a
file that exists and, where it names a heading, to that heading; the README stays short."""

import os
import re

import pytest

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
PAGES = ['README.md', 'CONTRIBUTING.md'] + sorted(
    os.path.join('docs', n) for n in os.listdir(os.path.join(ROOT, 'docs')) if n.endswith('.md'))
README_LINES = 250
"""Issue 29 item 6: a README read in five minutes."""
LINK = re.compile(r'\]\(([^)\s]+)\)')


def _slug(heading):
    """GitHub's anchor of a Markdown heading."""
    text = re.sub(r'[^\w\- ]', '', heading.strip().lower())
    return text.replace(' ', '-')


def _anchors(path):
    with open(path, encoding='utf-8') as fh:
        text = re.sub(r'```.*?```', '', fh.read(), flags=re.S)
    return {_slug(m) for m in re.findall(r'^#+ (.+)$', text, re.M)}


@pytest.mark.parametrize('page', PAGES)
def test_links_resolve(page):
    """Every relative link names an existing file, and an existing heading after ``#``."""
    with open(os.path.join(ROOT, page), encoding='utf-8') as fh:
        text = re.sub(r'```.*?```', '', fh.read(), flags=re.S)
    broken = []
    for target in LINK.findall(text):
        if re.match(r'[a-z]+:', target):
            continue
        path, _, anchor = target.partition('#')
        full = os.path.normpath(os.path.join(ROOT, os.path.dirname(page), path)) if path \
            else os.path.join(ROOT, page)
        if not os.path.exists(full):
            broken.append(target)
        elif anchor and full.endswith('.md') and anchor not in _anchors(full):
            broken.append(target)
    assert not broken, f'{page}: broken links {broken}'


def test_readme_is_short():
    with open(os.path.join(ROOT, 'README.md'), encoding='utf-8') as fh:
        lines = fh.read().count('\n')
    assert lines <= README_LINES, f'README.md has {lines} lines (at most {README_LINES})'
