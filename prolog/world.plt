:- begin_tests(world).
:- use_module(world).

test(valid_ids, [nondet]) :-
    forall(member(X, [a, "lab", 'c_w', "r1A_2"]), valid_id(X)).
test(invalid_ids, [nondet]) :-
    forall(member(X, ["", "A", "1a", "a-b", "a b", "a'), halt", 'x:y', "é", f(x), 3]),
           \+ valid_id(X)).
test(too_long, [nondet]) :-
    length(L, 65), maplist(=(0'a), L), atom_codes(A, L), \+ valid_id(A).
test(module_names_are_prefixed, [nondet]) :-
    world_module("lab", M), M == 'world:lab'.
test(worlds_are_isolated, [nondet, cleanup((drop_world(w_iso1), drop_world(w_iso2)))]) :-
    create_world(w_iso1), create_world(w_iso2),
    world_module(w_iso1, M1), world_module(w_iso2, M2),
    assertz(M1:rec(a, b)),
    \+ M2:rec(_, _),
    world_exists(w_iso1), world_exists(w_iso2).
test(drop_removes_facts, [nondet]) :-
    create_world(w_drop), world_module(w_drop, M), assertz(M:rec(a, b)),
    drop_world(w_drop),
    \+ M:rec(_, _), \+ world_exists(w_drop).
test(bad_name_throws, [nondet, throws(chizu_error(invalid_id(_)))]) :-
    create_world("Bad name").

:- end_tests(world).
