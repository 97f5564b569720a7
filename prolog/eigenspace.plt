/*  Fig. 4 localization states, the eigenspace facts, covers/triplet_distance
    and the eigenspace_* api ops.

    Fixture (metres):        2 (0,4) ---- 3 (4,4)
                              |  \   T1   / |
                              | T0  \    / T3 |
                              |       \/    |        T2 = 1, 4, 5
                             0 (0,0) - 1 (4,0) - 4 (8,0)    5 (8,4)
    T0 = [0,1,2], T1 = [1,3,2], T2 = [1,4,5], T3 = [1,5,3], T4 = [0,1,4]
    (collinear).  Candidate sets: 1 = {T0, T2}, 2 = {T1, T3}; T4 is in none.
*/
:- begin_tests(eigenspace).
:- use_module(library(http/json)).
:- use_module(world).
:- use_module(params).
:- use_module(eigenspace).
:- use_module(query).
:- use_module(api).

call_api(Op, Args, Reply) :-
    atom_json_dict(In, _{op:Op, args:Args, time_limit_s:5, inference_limit:10000000}, []),
    handle(In, Out),
    atom_json_dict(Out, Reply, []).

points([[0, 0], [4, 0], [0, 4], [4, 4], [8, 0], [8, 4]]).
triplets([ _{points:[0, 1, 2], directions_rad:[0.0, 1.5, 3.0], area_m2:8.0},
           _{points:[1, 3, 2], directions_rad:[0.5, 1.0, -1.0], area_m2:8},
           _{points:[1, 4, 5], directions_rad:[0.0, 0.0, 0.0], area_m2:8.0},
           _{points:[1, 5, 3], directions_rad:[3.1, 3.1, 3.1], area_m2:8.0},
           _{points:[0, 1, 4], directions_rad:[0.0, 0.0, 0.0], area_m2:0.0} ]).
sets([[0, 2], [1, 3]]).

eig_args(W, _{world:W, points:Ps, triplets:Ts, candidate_sets:Ss}) :-
    points(Ps), triplets(Ts), sets(Ss).

%   A world with the fixture, built through the api ops.
fixture(W) :-
    call_api(create_world, _{world:W, landmarks:[]}, R0), R0.ok == true,
    eig_args(W, Args),
    call_api(eigenspace_facts, Args, R), R.ok == true.

%   An eigenspace_facts call with one field replaced; Reply is the error.
bad_facts(W, Key, Value, Err) :-
    eig_args(W, Args0), put_dict(Key, Args0, Value, Args),
    call_api(eigenspace_facts, Args, R),
    R.ok == false, Err = R.error.
bad_triplet(W, Key, Value, Err) :-
    triplets([T0|Ts]), put_dict(Key, T0, Value, T),
    bad_facts(W, triplets, [T|Ts], Err).

close_to(X, Y) :- abs(X - Y) < 1.0e-9.

rank(x, 0).
rank(y(_), 1).
rank(z, 2).

		 /*******************************
		 *        FIG. 4 (STATES)       *
		 *******************************/

test(x_none, true(S == x)) :- next_state(x, none, S).
test(x_unique, true(S == z)) :- next_state(x, unique, S).
test(x_in_set, true(S == y(2))) :- next_state(x, in_set(2), S).
test(x_across, true(S == z)) :- next_state(x, across([1, 2]), S).
test(x_unlisted, true(S == y(unlisted))) :- next_state(x, unlisted, S).
test(y_none, true(S == y(3))) :- next_state(y(3), none, S).
test(y_unique, true(S == z)) :- next_state(y(3), unique, S).
test(y_same_set, true(S == y(3))) :- next_state(y(3), in_set(3), S).
test(y_other_set_common_element, true(S == z)) :- next_state(y(3), in_set(4), S).
test(y_across, true(S == z)) :- next_state(y(3), across([3, 4]), S).
test(y_unlisted_keeps_set, true(S == y(3))) :- next_state(y(3), unlisted, S).
test(y_unlisted_then_set, true(S == y(4))) :- next_state(y(unlisted), in_set(4), S).
test(y_unlisted_stays, true(S == y(unlisted))) :- next_state(y(unlisted), unlisted, S).
test(z_absorbing, [nondet]) :-
    forall(member(O, [none, unique, in_set(1), across([1, 2]), unlisted]),
           next_state(z, O, z)).
test(never_back, [nondet]) :-
    forall(( member(S0, [x, y(1), y(unlisted), z]),
             member(O, [none, unique, in_set(1), in_set(2), across([1, 2]), unlisted]) ),
           ( next_state(S0, O, S), rank(S0, R0), rank(S, R), R >= R0 )).
test(next_state_det, [true(Ss == [z])]) :-
    findall(S, next_state(y(1), in_set(2), S), Ss).
test(bad_state, [throws(chizu_error(invalid_state(w), state))]) :-
    next_state(w, none, _).
test(bad_outcome, [throws(chizu_error(invalid_outcome(across([1])), outcome))]) :-
    next_state(x, across([1]), _).
test(unbound_state, [throws(chizu_error(invalid_state(_), state))]) :-
    next_state(_, none, _).

		 /*******************************
		 *        STOP OUTCOMES         *
		 *******************************/

test(outcomes, [nondet, cleanup(drop_world(e1))]) :-
    fixture(e1),
    stop_outcome(e1, [], true, none),
    stop_outcome(e1, [0, 2], true, unique),
    stop_outcome(e1, [0, 2], false, in_set(1)),
    stop_outcome(e1, [2, 0, 2], false, in_set(1)),
    stop_outcome(e1, [3], false, in_set(2)),
    stop_outcome(e1, [3, 0], false, across([1, 2])),
    stop_outcome(e1, [0, 4], false, unlisted),
    stop_outcome(e1, [4], false, unlisted).
test(outcome_unknown_triplet, [cleanup(drop_world(e2)),
                               throws(chizu_error(unknown_triplet(5), triplets))]) :-
    fixture(e2), stop_outcome(e2, [0, 5], false, _).
test(outcome_bad_unique, [cleanup(drop_world(e3)),
                          throws(chizu_error(invalid_boolean(_), unique))]) :-
    fixture(e3), stop_outcome(e3, [0], _, _).
test(outcome_partial_list, [cleanup(drop_world(e4)),
                            throws(chizu_error(invalid_triplets(_), triplets))]) :-
    fixture(e4), stop_outcome(e4, [0|_], false, _).

test(state_after_folds, [nondet, cleanup(drop_world(e5))]) :-
    fixture(e5),
    state_after(e5, [], x),
    state_after(e5, [stop([], false)], x),
    state_after(e5, [stop([0, 2], false)], y(1)),
    state_after(e5, [stop([0, 2], false), stop([], false), stop([0], false)], y(1)),
    state_after(e5, [stop([0, 2], false), stop([1, 3], false)], z),
    state_after(e5, [stop([0, 4], false), stop([4], false)], y(unlisted)),
    state_after(e5, [stop([0, 4], false), stop([2], false)], y(1)),
    state_after(e5, [stop([0], false), stop([4], false), stop([1, 2], false)], z),
    state_after(e5, [stop([4], true), stop([], false), stop([0, 2], false)], z).
test(state_after_bad_stop, [cleanup(drop_world(e6)),
                            throws(chizu_error(invalid_stop(halt), stops))]) :-
    fixture(e6), state_after(e6, [stop([0], false), halt], _).

		 /*******************************
		 *           GEOMETRY           *
		 *******************************/

test(covers_inside, [nondet, cleanup(drop_world(e7)), true(Ts == [0])]) :-
    fixture(e7), findall(T, covers(e7, T, 1, 1), Ts).
test(covers_shared_edge, [nondet, cleanup(drop_world(e8)), true(Ts == [0, 1])]) :-
    fixture(e8), findall(T, covers(e8, T, 2.0, 2.0), Ts).
test(covers_degenerate_only_on_segment, [nondet, cleanup(drop_world(e9))]) :-
    fixture(e9),
    findall(T, covers(e9, T, 2, 0), [0, 4]),        % on T4's segment (and T0's edge)
    \+ covers(e9, 4, 10, 0),                        % on T4's line, beyond its ends
    \+ covers(e9, 4, 2, 1).
test(covers_outside, [nondet, cleanup(drop_world(e10)), true(Ts == [])]) :-
    fixture(e10), findall(T, covers(e10, T, -1, -1), Ts).
test(covers_tolerance_parameter, [nondet, cleanup(drop_world(e11)), true(Ts == [0, 4])]) :-
    %  (-1,-1) is sqrt(2) m from point 0
    fixture(e11), world_module(e11, M), assertz(M:parameter(eig_covers_tolerance_m, 1.5)),
    findall(T, covers(e11, T, -1, -1), Ts).
test(covers_tolerance_default, [true(V =:= 0.0)]) :-
    params:default_parameter(eig_covers_tolerance_m, V).
test(triplet_distance_values, [nondet, cleanup(drop_world(e12))]) :-
    fixture(e12),
    triplet_distance(e12, 0, 1, 1, D0), close_to(D0, sqrt(2)),
    triplet_distance(e12, 2, 6, 1, D2), close_to(D2, sqrt(5)),
    triplet_distance(e12, 3, 6, 1, D3), close_to(D3, sqrt(5)),
    triplet_distance(e12, 1, 0, 0, D1), close_to(D1, 4.0).
test(covers_bad_coordinate, [cleanup(drop_world(e13)),
                             throws(chizu_error(invalid_number(_), x))]) :-
    fixture(e13), covers(e13, _, _, 1).

		 /*******************************
		 *            FACTS             *
		 *******************************/

test(facts_stored, [nondet, cleanup(drop_world(e14))]) :-
    fixture(e14), world_module(e14, M),
    M:eig_point(5, X, Y), X == 8.0, Y == 4.0,
    M:eig_triplet(1, [1, 3, 2], [0.5, 1.0, -1.0], A), A == 8.0,
    findall(S-T, M:eig_candidate_set(S, T), [1-0, 1-2, 2-1, 2-3]).
test(facts_reply, [nondet, cleanup(drop_world(e15))]) :-
    call_api(create_world, _{world:"e15", landmarks:[]}, _),
    eig_args("e15", Args), call_api(eigenspace_facts, Args, R),
    R.result = _{world:"e15", points:6, triplets:5, candidate_sets:2}.
test(facts_replaced, [nondet, cleanup(drop_world(e16))]) :-
    fixture(e16),
    call_api(eigenspace_facts, _{world:"e16", points:[[0, 0], [1, 0], [0, 1]],
                                 triplets:[_{points:[0, 1, 2], directions_rad:[0, 0, 0],
                                             area_m2:0.5}],
                                 candidate_sets:[]}, R), R.ok == true,
    world_module(e16, M),
    aggregate_all(count, M:eig_point(_, _, _), 3),
    aggregate_all(count, M:eig_triplet(_, _, _, _), 1),
    \+ M:eig_candidate_set(_, _).
test(facts_op_lists_them, [nondet, cleanup(drop_world(e17))]) :-
    fixture(e17), call_api(facts, _{world:"e17"}, R),
    memberchk("eig_point(4,8.0,0.0)", R.result),
    memberchk("eig_triplet(4,[0,1,4],[0.0,0.0,0.0],0.0)", R.result),
    memberchk("eig_candidate_set(2,3)", R.result).
test(drop_and_clear_remove_them, [nondet]) :-
    fixture(e18), world_module(e18, M),
    clear_world(e18), \+ M:eig_point(_, _, _), \+ M:eig_triplet(_, _, _, _),
    fixture(e18), drop_world(e18),
    \+ M:eig_point(_, _, _), \+ M:eig_candidate_set(_, _).
test(worlds_do_not_share_eig_facts, [nondet, cleanup((drop_world(e19), drop_world(e20)))]) :-
    fixture(e19), create_world(e20),
    \+ covers(e20, _, 1, 1),
    catch(state_after(e20, [stop([0], false)], _), chizu_error(unknown_triplet(0), triplets), true).

		 /*******************************
		 *        API VALIDATION        *
		 *******************************/

test(facts_bad_point, [nondet, cleanup(drop_world(e21))]) :-
    fixture(e21),
    bad_facts(e21, points, [[0, 0], [1]], E1),
    E1.type == "invalid_point", E1.field == "points[1]",
    bad_facts(e21, points, [[0, "1"]], E2),
    E2.type == "invalid_number", E2.field == "points[0]",
    bad_facts(e21, points, _{x:1, y:2}, E3),
    E3.type == "invalid_list", E3.field == "points".
test(facts_bad_triplet_points, [nondet, cleanup(drop_world(e22))]) :-
    fixture(e22),
    bad_triplet(e22, points, [0, 1.0, 2], E1),
    E1.type == "invalid_index", E1.field == "triplets[0].points",
    bad_triplet(e22, points, [0, 1], E2),
    E2.type == "invalid_length", E2.field == "triplets[0].points",
    bad_triplet(e22, points, [0, 1, 6], E3),
    E3.type == "unknown_point", E3.value == 6, E3.field == "triplets[0].points",
    bad_triplet(e22, points, [0, 1, 1], E4),
    E4.type == "duplicate_point",
    bad_triplet(e22, points, [0, -1, 2], E5),
    E5.type == "invalid_index".
test(facts_bad_triplet_numbers, [nondet, cleanup(drop_world(e23))]) :-
    fixture(e23),
    bad_triplet(e23, directions_rad, [0.0, 1.0], E1),
    E1.type == "invalid_length", E1.field == "triplets[0].directions_rad",
    bad_triplet(e23, directions_rad, [0.0, 1.0, true], E2),
    E2.type == "invalid_number", E2.field == "triplets[0].directions_rad",
    bad_triplet(e23, area_m2, -1.0, E3),
    E3.type == "invalid_area", E3.field == "triplets[0].area_m2",
    bad_triplet(e23, area_m2, "8", E4),
    E4.type == "invalid_number", E4.field == "triplets[0].area_m2",
    triplets([T0|Ts]), del_dict(area_m2, T0, _, T),
    bad_facts(e23, triplets, [T|Ts], E5),
    E5.type == "missing", E5.field == "triplets[0].area_m2",
    bad_facts(e23, triplets, [[0, 1, 2]], E6),
    E6.type == "invalid_triplet", E6.field == "triplets[0]".
test(facts_bad_sets, [nondet, cleanup(drop_world(e24))]) :-
    fixture(e24),
    bad_facts(e24, candidate_sets, [[0, 9]], E1),
    E1.type == "unknown_triplet", E1.field == "candidate_sets[0][1]",
    bad_facts(e24, candidate_sets, [[0, 2], [1, 2]], E2),
    E2.type == "duplicate_triplet", E2.field == "candidate_sets[1][1]",
    bad_facts(e24, candidate_sets, [[0], []], E3),
    E3.type == "invalid_set", E3.field == "candidate_sets[1]",
    bad_facts(e24, candidate_sets, [["0"]], E4),
    E4.type == "invalid_index", E4.field == "candidate_sets[0][0]".
test(failed_facts_leave_old_ones, [nondet, cleanup(drop_world(e25))]) :-
    fixture(e25), world_module(e25, M),
    findall(F, ( member(N/A, [eig_point/3, eig_triplet/4, eig_candidate_set/2]),
                 functor(F, N, A), M:F ), Before),
    bad_facts(e25, candidate_sets, [[0, 99]], _),
    findall(F, ( member(N/A, [eig_point/3, eig_triplet/4, eig_candidate_set/2]),
                 functor(F, N, A), M:F ), After),
    Before == After, Before \== [].
test(facts_unknown_world, [nondet]) :-
    eig_args("nope", Args), call_api(eigenspace_facts, Args, R),
    R.error.type == "unknown_world", R.error.field == "world".

test(transition_op, [nondet, cleanup(drop_world(e26))]) :-
    fixture(e26),
    call_api(eigenspace_transition, _{world:"e26", state:_{state:"x"},
                                      triplets:[0, 2], unique:false}, R1),
    R1.result = _{outcome:"in_set", sets:[1], state:_{state:"y", set:1}},
    call_api(eigenspace_transition, _{world:"e26", state:R1.result.state,
                                      triplets:[3], unique:false}, R2),
    R2.result = _{outcome:"in_set", sets:[2], state:_{state:"z"}},
    call_api(eigenspace_transition, _{world:"e26", state:_{state:"x"},
                                      triplets:[4], unique:false}, R3),
    R3.result = _{outcome:"unlisted", sets:[], state:_{state:"y", set:"unlisted"}},
    call_api(eigenspace_transition, _{world:"e26", state:_{state:"y", set:"unlisted"},
                                      triplets:[0, 1], unique:false}, R4),
    R4.result = _{outcome:"across", sets:[1, 2], state:_{state:"z"}},
    call_api(eigenspace_transition, _{world:"e26", state:_{state:"y", set:2},
                                      triplets:[], unique:true}, R5),
    R5.result = _{outcome:"none", sets:[], state:_{state:"y", set:2}},
    call_api(eigenspace_transition, _{world:"e26", state:_{state:"y", set:"unlisted"},
                                      triplets:[], unique:false}, R6),
    R6.result = _{outcome:"none", sets:[], state:_{state:"y", set:"unlisted"}},
    call_api(eigenspace_transition, _{world:"e26", state:_{state:"z", set:null},
                                      triplets:[4], unique:false}, R7),
    R7.result = _{outcome:"unlisted", sets:[], state:_{state:"z"}}.
test(transition_op_errors, [nondet, cleanup(drop_world(e27))]) :-
    fixture(e27),
    T = _{world:"e27", state:_{state:"x"}, triplets:[0], unique:false},
    call_api(eigenspace_transition, T.put(triplets, [0, 99]), R1),
    R1.error.type == "unknown_triplet", R1.error.field == "triplets", R1.error.value == 99,
    call_api(eigenspace_transition, T.put(triplets, [0.0]), R2),
    R2.error.type == "invalid_triplets", R2.error.field == "triplets",
    call_api(eigenspace_transition, T.put(unique, "true"), R3),
    R3.error.type == "invalid_boolean", R3.error.field == "unique",
    call_api(eigenspace_transition, T.put(state, _{state:"y", set:7}), R4),
    R4.error.type == "unknown_set", R4.error.field == "state.set",
    call_api(eigenspace_transition, T.put(state, _{state:"y"}), R5),
    R5.error.type == "missing", R5.error.field == "state.set",
    call_api(eigenspace_transition, T.put(state, _{state:"w"}), R6),
    R6.error.type == "invalid_state", R6.error.field == "state.state",
    call_api(eigenspace_transition, T.put(state, "x"), R7),
    R7.error.type == "invalid_state", R7.error.field == "state",
    call_api(eigenspace_transition, T.put(state, _{state:"z", set:1}), R8),
    R8.error.type == "unexpected", R8.error.field == "state.set",
    del_dict(unique, T, _, T9), call_api(eigenspace_transition, T9, R9),
    R9.error.type == "missing", R9.error.field == "unique".

test(covering_op, [nondet, cleanup(drop_world(e28))]) :-
    fixture(e28),
    call_api(eigenspace_covering, _{world:"e28", x:2, y:2}, R),
    R.result = [C0, C1],
    C0.triplet == 0, close_to(C0.distance_m, sqrt(8)),
    C1.triplet == 1, close_to(C1.distance_m, sqrt(8)),
    call_api(eigenspace_covering, _{world:"e28", x:6.0, y:1.0}, R2),
    R2.result = [C2], C2.triplet == 2, close_to(C2.distance_m, sqrt(5)),
    call_api(eigenspace_covering, _{world:"e28", x: -5, y:0}, R3), R3.result == [],
    call_api(eigenspace_covering, _{world:"e28", x:"1", y:0}, R4),
    R4.error.type == "invalid_number", R4.error.field == "x",
    call_api(eigenspace_covering, _{world:"e28", x:1}, R5),
    R5.error.type == "missing", R5.error.field == "y".

		 /*******************************
		 *          INJECTION           *
		 *******************************/

test(injection_in_world_name, [nondet]) :-
    findall(W, world_exists(W), Before),
    eig_args("e29), assertz(pwned), (", Args),
    call_api(eigenspace_facts, Args, R),
    R.error.type == "invalid_id", R.error.field == "world",
    call_api(eigenspace_transition, _{world:"x), halt, (", state:_{state:"x"},
                                      triplets:[], unique:false}, R2),
    R2.error.type == "invalid_id",
    findall(W, world_exists(W), After),
    After == Before,
    \+ catch(user:pwned, _, fail).
test(injection_in_triplets_and_state, [nondet, cleanup(drop_world(e30))]) :-
    fixture(e30),
    call_api(eigenspace_transition, _{world:"e30", state:_{state:"x"},
                                      triplets:"[0]), assertz(pwned), ([0]",
                                      unique:false}, R1),
    R1.error.type == "invalid_triplets", R1.error.field == "triplets",
    call_api(eigenspace_transition, _{world:"e30", state:_{state:"y",
                                                          set:"1), assertz(pwned), (1"},
                                      triplets:[0], unique:false}, R2),
    R2.error.type == "invalid_set", R2.error.field == "state.set",
    call_api(eigenspace_transition, _{world:"e30", state:_{state:"halt"},
                                      triplets:[0], unique:false}, R3),
    R3.error.type == "invalid_state",
    bad_triplet(e30, points, "assertz(pwned)", E4),
    E4.type == "invalid_length",
    \+ catch(user:pwned, _, fail).

		 /*******************************
		 *        QUERY AND REPL        *
		 *******************************/

test(query_whitelist, [nondet, cleanup(drop_world(e31))]) :-
    fixture(e31),
    world_query(e31, "state_after([stop([0, 2], false), stop([1], false)], S)", 5, [S1], false),
    S1.'S' == "z",
    world_query(e31, "covers(T, 1, 1), triplet_distance(T, 1, 1, D)", 5, [S2], false),
    S2.'T' == 0, close_to(S2.'D', sqrt(2)),
    world_query(e31, "eig_candidate_set(2, T)", 5, [_, _], false),
    world_query(e31, "stop_outcome([0, 3], false, O), next_state(y(1), O, N)", 5, [S3], false),
    S3.'O' == "across([1,2])", S3.'N' == "z",
    catch(( world_query(e31, "covers(T, 1, 1), assertz(pwned)", 5, _, _), fail ),
          chizu_error(not_allowed(assertz/1), goal), true),
    \+ catch(user:pwned, _, fail).
test(repl_helpers, [nondet, cleanup(drop_world(e32))]) :-
    fixture(e32),
    repl:use_world(e32),
    repl:state_after([stop([0, 2], false)], S), S == y(1),
    repl:covers(1, 3, 3), \+ repl:covers(0, 3, 3),
    repl:triplet_distance(2, 8, 0, D), D =:= 0,
    repl:stop_outcome([1, 3], false, O), O == in_set(2).

:- end_tests(eigenspace).
