"""RunContext.resources: per-run objects shared by typed keys."""
from runtime.tree.resources import WAYPOINTS, Resource, Resources

COUNTS: Resource[list[int]] = Resource("test.counts")


def test_a_key_not_set_reads_none_and_is_not_contained() -> None:
    resources = Resources()
    assert resources.get(COUNTS) is None
    assert COUNTS not in resources


def test_set_then_get_returns_the_same_object() -> None:
    resources, home = Resources(), {"Home": {"shoulder_pan_joint": 0.0}}
    resources.set(WAYPOINTS, home)
    assert resources.get(WAYPOINTS) is home
    assert WAYPOINTS in resources


def test_setdefault_makes_the_object_once() -> None:
    resources, made = Resources(), []

    def make() -> list[int]:
        made.append(1)
        return []

    resources.setdefault(COUNTS, make).append(1)
    resources.setdefault(COUNTS, make).append(2)
    assert resources.get(COUNTS) == [1, 2]
    assert made == [1]


def test_two_keys_of_one_name_share_the_object() -> None:
    resources = Resources()
    resources.set(COUNTS, [3])
    assert resources.get(Resource[list[int]]("test.counts")) == [3]
    assert repr(COUNTS) == "Resource('test.counts')"
