:- begin_tests(query).
:- use_module(world).
:- use_module(qualitative).
:- use_module(query).

w(Name, Facts) :-
    create_world(Name), world_module(Name, M),
    forall(member(F, Facts), assertz(M:F)), invalidate(Name).

test(relation_query, [nondet, cleanup(drop_world(s1))]) :-
    w(s1, [rec(a, b), rec(b, c)]),
    world_query(s1, "rec(a, X, P), P >= 0.9", 10, Sols, false),
    Sols = [S], S.'X' == "b", S.'P' =:= 1.0.
test(reachable_query, [nondet, cleanup(drop_world(s2))]) :-
    w(s2, [rec(a, b), rea(b, c)]),
    world_query(s2, "reachable(a, To, P, M)", 10, Sols, false),
    Sols = [S], S.'To' == "b", S.'M' == "move1".
test(truncated, [nondet, cleanup(drop_world(s3))]) :-
    w(s3, [rec(a, b), rec(a, c), rec(a, d)]),
    world_query(s3, "rec(a, X, _)", 2, Sols, Trunc),
    length(Sols, 2), Trunc == true.
test(not_allowed, [nondet, cleanup(drop_world(s4))]) :-
    w(s4, []),
    forall(member(G, ["halt", "assertz(pwned)", "shell('ls')", "call(halt)",
                      "rec(a, X, _), halt", "\\+ format(\"x\")", "X", "open(f, write, S)",
                      "'world:s4':rec(a, b)", "qualitative:rec(s4, a, b, P)"]),
           catch(( world_query(s4, G, 5, _, _), fail ),
                 chizu_error(not_allowed(_), goal), true)),
    \+ catch(user:pwned, _, fail).
test(no_arithmetic_bombs, [nondet, cleanup(drop_world(s5)), throws(chizu_error(not_allowed(_), goal))]) :-
    w(s5, []),
    world_query(s5, "1 < 2**100000000", 5, _, _).
test(syntax_error, [nondet, cleanup(drop_world(s6)), throws(chizu_error(syntax_error(_), goal))]) :-
    w(s6, []),
    world_query(s6, "rec(a, ", 5, _, _).
:- end_tests(query).
