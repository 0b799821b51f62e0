"""config.py's parts on small configs of the tests' own (the suite's configs never use a flag
name in an error, an ``upgrade``, a repeated key or most of the parser's branches).

The classes are made inside the tests, not at import: ``setting`` and ``nested`` then run while a
test runs (mutation testing switches a mutant on only then). No ``from __future__ import
annotations`` here: the annotations of a class made in a function must be types, not names."""
import dataclasses
import math
from dataclasses import dataclass
from typing import Dict, Optional, Tuple, Union

import pytest

from trl_dgpq.config import (Interval, Leaf, check_config, check_value, describe_default, find_leaf, from_dict,
                             leaves, nested, parse_value, setting)


def leaf(tp, name="x"):
    return Leaf(name, (name,), tp, dataclasses.field())


def test_setting_and_nested_declare_their_metadata():
    parse = str.upper
    f = setting(3, "three", choices=(3, 4), flag="fancy", parse=parse, within="[0, 5)", length=(1, 2))
    assert f.default == 3 and dict(f.metadata) == dict(help="three", choices=(3, 4), flag="fancy", parse=parse,
                                                       within=Interval(0.0, 5.0, True, False), length=(1, 2))
    assert setting(1, "h").metadata["within"] is None

    @dataclass
    class Documented:
        """what it holds"""
        a: int = setting(1, "a")

    @dataclass
    class Bare:
        a: int = setting(1, "a")
    Bare.__doc__ = None
    made = nested(Documented)
    assert made.default_factory is Documented and dict(made.metadata) == {"help": "what it holds"}
    assert dict(nested(Bare).metadata) == {"help": ""}


def test_a_flag_name_is_the_key_in_leaves_and_in_every_error():
    @dataclass
    class Inner:
        count: int = setting(2, "a count", flag="fancy_count", within="[0, inf)")

    @dataclass
    class Outer:
        inner: Inner = nested(Inner)
        rate: float = setting(0.5, "a rate")
    (first, second) = leaves(Outer)
    assert (first.key, first.path, first.help) == ("fancy_count", ("inner", "count"), "a count")
    assert (second.key, second.path) == ("rate", ("rate",))
    assert find_leaf(Outer, "fancy_count") == first and find_leaf(Outer, "inner.count") == first
    assert find_leaf(Outer, "count") is None
    with pytest.raises(ValueError, match=r"^fancy_count must be >= 0, got -1$"):
        check_config(Outer(Inner(-1)))
    with pytest.raises(ValueError, match=r"^fancy_count must be an integer, got 'two'$"):
        from_dict(Outer, {"inner": {"count": "two"}})
    assert from_dict(Outer, {"inner": {"count": "4"}, "rate": "0.25"}) == Outer(Inner(4), 0.25)


def test_a_name_that_is_one_leafs_key_and_anothers_path_finds_the_first_in_field_order():
    @dataclass
    class Inner:
        size: int = setting(2, "a size", flag="rate")

    @dataclass
    class First:
        rate: float = setting(0.5, "a rate", flag="speed")
        inner: Inner = nested(Inner)

    @dataclass
    class Second:
        inner: Inner = nested(Inner)
        rate: float = setting(0.5, "a rate", flag="speed")
    assert find_leaf(First, "rate").path == ("rate",) and find_leaf(Second, "rate").path == ("inner", "size")
    assert find_leaf(First, "speed").path == ("rate",) and find_leaf(First, "inner.size").key == "rate"
    assert find_leaf(First, "size") is None and find_leaf(First, "inner") is None


def test_a_key_used_twice_in_one_tree_is_refused_naming_it():
    @dataclass
    class A:
        lr: float = setting(0.1, "a")
        other: int = setting(1, "b")

    @dataclass
    class B:
        lr: float = setting(0.2, "c")

    @dataclass
    class Both:
        a: A = nested(A)
        b: B = nested(B)
    with pytest.raises(TypeError, match=r"^Both: setting names must be unique, repeated: \['lr'\]$"):
        leaves(Both)


def test_from_dict_refuses_what_is_not_a_mapping_and_upgrades_an_old_layout():
    @dataclass
    class Renamed:
        new: int = setting(1, "renamed from old")

        @classmethod
        def upgrade(cls, d):
            return {"new" if k == "old" else k: v for k, v in d.items()}
    assert from_dict(Renamed, {"old": 7}) == Renamed(7)
    with pytest.raises(ValueError, match=r"^Renamed settings must be a mapping, got list$"):
        from_dict(Renamed, [1])
    with pytest.raises(ValueError, match=r"^unknown Renamed settings: \['other'\]$"):
        from_dict(Renamed, {"other": 1})


@pytest.mark.parametrize("length, items, message", [
    (2, (1,), "x needs 2 values, got [1]"),
    (1, (1, 2), "x needs 1 value, got [1, 2]"),
    ((1, 1), (), "x needs 1 value, got []"),
    ((1, None), (), "x needs at least 1 value, got []"),
    ((2, None), (1,), "x needs at least 2 values, got [1]"),
    ((1, 3), (1, 2, 3, 4), "x needs 1 to 3 values, got [1, 2, 3, 4]"),
])
def test_a_tuples_length_is_refused_in_words(length, items, message):
    with pytest.raises(ValueError) as err:
        check_value("x", {"length": length}, items)
    assert str(err.value) == message


def test_bounds_choices_and_none_are_checked_per_value_or_item():
    within = Interval.parse("[0, 1]")
    check_value("x", {"within": within, "length": (1, None)}, None)            # None: "not given"
    check_value("x", {"within": within, "length": 2}, (0.0, 1.0))
    with pytest.raises(ValueError, match=r"^x must each be in \[0, 1\], got \[0.5, 2\]$"):
        check_value("x", {"within": within}, (0.5, 2))
    with pytest.raises(ValueError, match=r"^x must be in \[0, 1\], got 2$"):
        check_value("x", {"within": within}, 2)
    with pytest.raises(ValueError, match=r"^x must be one of \['a', 'b'\], got 'c'$"):
        check_value("x", {"choices": ("a", "b")}, "c")


@pytest.mark.parametrize("text, value", [("true", True), ("TRUE", True), (" Yes ", True), ("1", True), ("on", True),
                                         ("ON", True), ("false", False), ("False", False), ("0", False),
                                         ("no", False), ("NO", False), ("off", False), ("OFF", False),
                                         (True, True), (False, False)])
def test_booleans_are_read_from_each_word_for_them(text, value):
    assert parse_value(leaf(bool), text) is value


def test_each_type_is_parsed_and_each_misfit_named_in_one_line():
    assert parse_value(leaf(Optional[int]), " NULL ") is None and parse_value(leaf(Optional[int]), "null") is None
    assert parse_value(leaf(Optional[int]), "None") is None and parse_value(leaf(Optional[int]), "3") == 3
    assert parse_value(leaf(Optional[Tuple[int, ...]]), "1, 2") == (1, 2)
    assert parse_value(leaf(Tuple[str, ...]), "a, b,") == ("a", "b")
    assert parse_value(leaf(Tuple[str, ...]), ["a", " b"]) == ("a", "b")
    assert parse_value(leaf(float), "2.5") == 2.5 and parse_value(leaf(int), 4.0) == 4
    assert parse_value(leaf(str), "text") == "text"
    refusals = [(int, None, "x cannot be none"), (bool, "maybe", "x must be true or false, got 'maybe'"),
                (int, True, "x must be an integer, got True"), (int, 2.5, "x must be an integer, got 2.5"),
                (float, True, "x must be a number, got True"), (float, "fast", "x must be a number, got 'fast'"),
                (str, 3, "x must be text, got 3"),
                (Tuple[int, ...], 3, "x must be a comma-separated list, got 3"),
                (Tuple[int, ...], "1,a", "x must be a comma-separated list of int, got '1,a'")]
    for tp, value, message in refusals:
        with pytest.raises(ValueError) as err:
            parse_value(leaf(tp), value)
        assert str(err.value) == message, (tp, value)
    for tp in (Union[int, str], Dict[str, int]):
        with pytest.raises(TypeError) as err:
            parse_value(leaf(tp), "1")
        assert str(err.value) == f"x: unsupported setting type {tp}"
    custom = Leaf("x", ("x",), int, setting(0, "h", parse=lambda v: f"parsed {v}"))
    assert parse_value(custom, "a") == "parsed a"


@pytest.mark.parametrize("text, words", [
    ("(-inf, inf)", "finite"), ("[-inf, inf]", "in [-inf, inf]"), ("[-inf, inf)", "in [-inf, inf)"),
    ("(-inf, 3]", "<= 3"), ("(-inf, 3)", "< 3"), ("[0, inf)", ">= 0"), ("(0, inf)", "> 0"),
    ("[0, 1)", "in [0, 1)"), ("(0, 1]", "in (0, 1]"), (" [ 1E-3 , 2e1 ] ", "in [0.001, 20]"),
])
def test_an_interval_reads_and_says_its_ends(text, words):
    assert str(Interval.parse(text)) == words


def test_an_interval_holds_numbers_between_its_ends_and_infinity_only_at_a_closed_end():
    closed, half = Interval.parse("[0, inf]"), Interval.parse("(0, 1]")
    assert Interval.parse("[1E-3, 2]") == Interval(0.001, 2.0, True, True)
    assert math.inf in closed and 0 in closed and -1 not in closed and math.nan not in closed
    assert math.inf not in Interval.parse("[0, inf)") and -math.inf in Interval.parse("[-inf, 0]")
    assert 1 in half and 0 not in half and 0.5 in half and 1.5 not in half
    assert True not in half and "0.5" not in half and None not in half
    with pytest.raises(TypeError) as err:
        Interval.parse("0..1")
    assert str(err.value) == "not an interval: '0..1' (write e.g. [0, 1] or (0, inf))"


def test_a_default_is_described_as_the_command_line_writes_it():
    def described(default):
        return describe_default(Leaf("x", ("x",), object, setting(default, "h")))
    assert described((64, 32)) == "64,32" and described(()) == "(none)" and described(0.5) == "0.5"
    assert described(None) == "None"
