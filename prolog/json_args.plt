:- begin_tests(json_args).
:- use_module(json_args).
:- use_module(world).

test(missing_argument, [throws(chizu_error(missing(world), world))]) :-
    arg_(world, _{}, _).
test(item_value_names_its_field, [throws(chizu_error(missing(x), "regions[2].x"))]) :-
    dict_value(_{y:1}, x, "regions[2].x", _).
test(finite_numbers, [nondet]) :-
    forall(member(V, [0, 1, -2.5, 1.0e300, 12345678901234567890]), finite_number(V, f)),
    finite_float(f, 3, F), F == 3.0.
test(inf_and_nan_are_refused, [nondet]) :-
    Inf is inf, NaN is nan,
    forall(member(V, [Inf, NaN, "1", x, 10^400]),
           catch((finite_number(V, f), fail), chizu_error(invalid_number(_), f), true)).
test(nonneg_refuses_negatives, [throws(chizu_error(invalid_number(-1), area))]) :-
    nonneg_float(area, -1, _).
test(index_in_range, [nondet]) :-
    index_in(2, 3, unknown_point, f),
    catch(index_in(3, 3, unknown_point, f), chizu_error(unknown_point(3), f), true),
    catch(index_in(1.0, 3, unknown_point, f), chizu_error(invalid_index(1.0), f), true).
test(ids_become_atoms_only_when_valid, [throws(chizu_error(invalid_id("a'), halt"), world))]) :-
    id_field("a'), halt", world, _).
test(unknown_world, [throws(chizu_error(unknown_world(nowhere_ja), world))]) :-
    existing_world(_{world:"nowhere_ja"}, _).
test(known_landmark, [nondet, cleanup(drop_world(w_ja))]) :-
    create_world(w_ja), world_module(w_ja, M), assertz(M:landmark(a)),
    known_landmark(w_ja, "a", at, a),
    catch(known_landmark(w_ja, "b", at, _), chizu_error(unknown_landmark(b), at), true).
test(every_domain_declares_its_facts, [nondet]) :-
    forall(member(D, [world, qualitative, eigenspace, slam, viewpoint]), domain_fact(D, _)),
    \+ ( domain_fact(D1, PI), domain_fact(D2, PI), D1 \== D2 ).

:- end_tests(json_args).
