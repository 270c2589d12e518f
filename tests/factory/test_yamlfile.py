"""User YAML within bounds: anchors and merge keys read as before; alias bombs, recursion and
syntax errors end in one line naming the file and line."""

from __future__ import annotations

import pytest
import yaml
from hypothesis import given, settings
from hypothesis import strategies as st

from factory.core.errors import FactoryError
from factory.core.yamlfile import load_yaml
from tests.cli.hostile import alias_bomb


def test_anchors_and_merge_keys_read_like_safe_load():
    text = "base: &b {feed: 300, rpm: 9000}\ntools:\n  - {<<: *b, number: 1}\n  - {<<: *b, number: 2, rpm: 12000}\n"
    assert load_yaml(text, source="t.yaml", error=FactoryError) == yaml.safe_load(text)


@pytest.mark.parametrize("levels, refused", [(6, False), (7, True)])
def test_expansion_is_counted_through_aliases(levels, refused):
    text = "x: " + alias_bomb(levels=levels) + "\n"  # 9**levels strings
    if refused:
        with pytest.raises(FactoryError, match="more than 1,000,000 values") as e:
            load_yaml(text, source="b.yaml", error=FactoryError)
        assert e.value.source == "b.yaml:1"
    else:
        assert len(load_yaml(text, source="b.yaml", error=FactoryError)["x"]) == levels


def test_limit_is_a_parameter():
    text = "a: &a [1, 2, 3]\nb: [*a, *a, *a]\n"  # mapping 1 + keys 2 + a (1+3) + b (1 + 3*4) = 20 values
    assert load_yaml(text, source="s.yaml", error=FactoryError, max_values=20)
    with pytest.raises(FactoryError, match="more than 19 values"):
        load_yaml(text, source="s.yaml", error=FactoryError, max_values=19)


@pytest.mark.parametrize("text, where, what", [
    ("a: &a [*a]\n", "r.yaml:1", "recursive alias"),
    ("a: [1, 2\nb: 3\n", "r.yaml:2", "not valid YAML"),
    ("a: 1\n---\nb: 2\n", "r.yaml:2", "not valid YAML"),
    ("\x1f", "r.yaml", "not valid YAML"),
    ("a: " + "[" * 3000 + "]" * 3000, "r.yaml", "nested too deeply"),
])
def test_bad_documents_are_one_line(text, where, what):
    with pytest.raises(FactoryError) as e:
        load_yaml(text, source="r.yaml", error=FactoryError)
    assert e.value.source == where and what in e.value.message and "\n" not in str(e.value)


@settings(max_examples=150, deadline=None)
@given(st.text(alphabet=st.sampled_from(list("ab:-[]{},&*!|>'\"#\n x1")), max_size=80))
def test_any_text_reads_or_is_one_factory_error(text):
    try:
        load_yaml(text, source="f.yaml", error=FactoryError)
    except FactoryError as e:
        assert str(e).startswith("f.yaml") and "\n" not in str(e)
