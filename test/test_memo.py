"""The identity-keyed memo the pairing and solver share (memo.per_objects)."""
from nao_skin.touch import memo


def test_keeps_what_is_asked_for_and_forgets_the_oldest(monkeypatch):
    monkeypatch.setattr(memo, "_STORE", {})
    monkeypatch.setattr(memo, "_LIMIT", 3)
    computed = []

    def ask(owner, key="k"):
        return memo.per_objects((owner,), (key,), lambda: computed.append((owner, key)) or len(computed))

    a, b, c, d = (object() for _ in range(4))
    assert [ask(a), ask(b), ask(c)] == [1, 2, 3]
    assert ask(a) == 1                       # a hit, and now the most recently used
    assert ask(d) == 4                       # full: b, the least recently used, goes
    assert ask(a) == 1 and ask(c) == 3 and ask(d) == 4 and len(computed) == 4
    assert ask(b) == 5                       # computed again
    assert ask(a, "other") == 6              # the key is part of the identity


def test_a_reused_id_never_returns_another_objects_result(monkeypatch):
    monkeypatch.setattr(memo, "_STORE", {})
    first = object()
    assert memo.per_objects((first,), ("k",), lambda: "first") == "first"
    # pretend a new object got the same id: the stored owner is not it, so compute afresh
    key = next(iter(memo._STORE))
    owners, value = memo._STORE[key]
    memo._STORE[key] = ((object(),), value)
    assert memo.per_objects((first,), ("k",), lambda: "again") == "again"
