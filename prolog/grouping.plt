/*  Observation groups (grouping.pl) and the viewpoint_groups / viewpoint_scene
    api ops.

    Fixture (metres): candidates c1 (0,0) r 1.0, c2 (1.5,0) r 1.0 (1.5 < 2:
    joined), c3 (3.2,0) r 1.0 (1.7 < 2 with c2, so c1-c3 transitively),
    c4 (10,10) r 0.5 alone, c5 (10,11.2) r 0.5 alone (1.2 > 1.0);
    unknown regions 0 (2.0 m2), 1 (0.3 m2: below 0.5) and 2 (0.5 m2: exactly
    the default threshold, so a group).  Groups: 0 = [c1,c2,c3], 1 = [c4],
    2 = [c5], 3 = region 0, 4 = region 2.
*/
:- begin_tests(grouping).
:- use_module(library(http/json)).
:- use_module(library(apply)).
:- use_module(library(lists)).
:- use_module(library(random)).
:- use_module(world).
:- use_module(grouping).
:- use_module(query).
:- use_module(api).

call_api(Op, Args, Reply) :-
    atom_json_dict(In, _{op:Op, args:Args, time_limit_s:5, inference_limit:10000000}, []),
    handle(In, Out),
    atom_json_dict(Out, Reply, []).

candidates([_{id:"c1", type:"A", x:0, y:0, r_max:1.0},
            _{id:"c2", type:"A", x:1.5, y:0, r_max:1},
            _{id:"c3", type:"mug", x:3.2, y:0.0, r_max:1.0},
            _{id:"c4", type:"B", x:10, y:10, r_max:0.5},
            _{id:"c5", type:"B", x:10, y:11.2, r_max:0.5}]).
regions([_{id:0, x:0, y:5, area_m2:2.0},
         _{id:1, x:5, y:5, area_m2:0.3},
         _{id:2, x:8, y:1, area_m2:0.5}]).

scene_args(W, _{world:W, candidates:Cs, regions:Rs}) :-
    candidates(Cs), regions(Rs).

new_world(W) :-
    call_api(create_world, _{world:W, landmarks:[]}, R), R.ok == true.

%   A world with the fixture, built through the api ops; Reply is the reply.
fixture(W, Reply) :-
    new_world(W),
    scene_args(W, Args),
    call_api(viewpoint_groups, Args, Reply), Reply.ok == true.
fixture(W) :- fixture(W, _).

%   A viewpoint_groups call on W's fixture with one field replaced.
bad_scene(W, Key, Value, Err) :-
    scene_args(W, Args0), put_dict(Key, Args0, Value, Args),
    call_api(viewpoint_groups, Args, R),
    R.ok == false, Err = R.error.

%   The fixture with candidate I's Key set to Value (Value = '$del': removed).
bad_candidate(W, I, Key, Value, Err) :-
    candidates(Cs0), nth0(I, Cs0, C0),
    (   Value == '$del' -> del_dict(Key, C0, _, C) ; put_dict(Key, C0, Value, C) ),
    replace_nth0(I, Cs0, C, Cs),
    bad_scene(W, candidates, Cs, Err).
bad_region(W, I, Key, Value, Err) :-
    regions(Rs0), nth0(I, Rs0, R0),
    (   Value == '$del' -> del_dict(Key, R0, _, R) ; put_dict(Key, R0, Value, R) ),
    replace_nth0(I, Rs0, R, Rs),
    bad_scene(W, regions, Rs, Err).

replace_nth0(I, L0, X, L) :-
    nth0(I, L0, _, Rest), nth0(I, L, X, Rest).

error_is(E, Type, Field) :- E.type == Type, E.field == Field.

scene_facts(W, Fs) :-
    world_module(W, M),
    findall(F, ( (   grouping_fact(N/A), functor(F, N, A)
                 ;   F = unknown_region(scene, _, _, _, _) ), M:F ), Fs).

groups(W, Gs) :- findall(G-K-Ms, observation_group(W, G, K, Ms), Gs).

%   Id-Members of the reply's groups (of Kind, or all).
reply_groups(Reply, IMs) :- reply_groups(Reply, _, IMs).
reply_groups(Reply, Kind, IMs) :-
    findall(I-Ms, ( member(G, Reply.result.groups), group_of_kind(G, Kind, I, Ms) ), IMs).

group_of_kind(G, Kind, I, Ms) :-
    get_dict(kind, G, Kind), get_dict(id, G, I), get_dict(members, G, Ms).

		 /*******************************
		 *            GROUPS            *
		 *******************************/

test(groups_and_numbering, [nondet, cleanup(drop_world(g1))]) :-
    fixture("g1", R),
    R.result.min_area_m2 == 0.5,
    R.result.groups =@= [ _{id:0, kind:"objects", members:["c1", "c2", "c3"]},
                         _{id:1, kind:"objects", members:["c4"]},
                         _{id:2, kind:"objects", members:["c5"]},
                         _{id:3, kind:"unknown", members:[0], area_m2:2.0},
                         _{id:4, kind:"unknown", members:[2], area_m2:0.5} ],
    groups(g1, Gs),
    Gs == [0-objects-[c1, c2, c3], 1-objects-[c4], 2-objects-[c5],
           3-unknown-[0], 4-unknown-[2]].
test(transitive_joining, [nondet, cleanup(drop_world(g2))]) :-
    fixture("g2"),
    joinable(g2, c1, c2), joinable(g2, c2, c1), joinable(g2, c2, c3),
    \+ joinable(g2, c1, c3), \+ joinable(g2, c1, c1),
    same_group(g2, c1, c3), same_group(g2, c3, c1), same_group(g2, c2, c2),
    \+ same_group(g2, c1, c4),
    findall(X, same_group(g2, c1, X), Xs), msort(Xs, [c1, c2, c3]),
    findall(A-B, joinable(g2, A, B), Ps), msort(Ps, [c1-c2, c2-c1, c2-c3, c3-c2]).
test(boundary_does_not_join, [nondet, cleanup(drop_world(g3))]) :-
    fixture("g3"),
    \+ joinable(g3, c4, c5), \+ same_group(g3, c4, c5),
    %  distances exactly equal to the sum: 2.0 = 1 + 1 and 5.0 = 0.5 + 4.5
    replace_viewpoint_scene(g3, [vp_candidate(a, "t", 0, 0, 1), vp_candidate(b, "t", 2, 0, 1),
                                 vp_candidate(p, "t", 0, 50, 0.5), vp_candidate(q, "t", 3, 54, 4.5),
                                 vp_candidate(u, "t", 100, 0, 0.5),
                                 vp_candidate(v, "t", 103, 4, 4.500001)], [], 0.5),
    \+ joinable(g3, a, b), \+ joinable(g3, p, q), joinable(g3, u, v),
    groups(g3, Gs),
    Gs == [0-objects-[a], 1-objects-[b], 2-objects-[p], 3-objects-[q], 4-objects-[u, v]].
test(area_threshold, [nondet, cleanup(drop_world(g4))]) :-
    fixture("g4"),
    findall(G-A, unknown_group_area(g4, G, A), GAs), GAs == [3-2.0, 4-0.5],
    \+ observation_group(g4, _, unknown, [1]),
    world_module(g4, M), M:unknown_region(scene, 1, 5.0, 5.0, 0.3), M:vp_min_area(0.5).
test(custom_min_area, [nondet, cleanup(drop_world(g5))]) :-
    fixture("g5"),
    scene_args("g5", A0),
    call_api(viewpoint_groups, A0.put(min_area_m2, 1), R1),
    R1.result.min_area_m2 =:= 1.0,
    reply_groups(R1, "unknown", U1), U1 == [3-[0]],
    call_api(viewpoint_groups, A0.put(min_area_m2, 0), R2),
    reply_groups(R2, "unknown", U2), U2 == [3-[0], 4-[1], 5-[2]],
    call_api(viewpoint_groups, A0.put(min_area_m2, null), R3),
    R3.result.min_area_m2 == 0.5.
test(world_parameter_is_the_default, [nondet, cleanup(drop_world(g6))]) :-
    call_api(create_world, _{world:"g6", landmarks:[],
                             parameters:_{unknown_region_min_area_m2:0.25}}, R0), R0.ok == true,
    call_api(viewpoint_scene, _{world:"g6"}, S0), S0.result.min_area_m2 =:= 0.25,
    scene_args("g6", Args), call_api(viewpoint_groups, Args, R),
    R.result.min_area_m2 =:= 0.25,
    reply_groups(R, "unknown", U), U == [3-[0], 4-[1], 5-[2]].
test(numbering_by_member_order, [nondet, cleanup(drop_world(g7))]) :-
    new_world("g7"),
    call_api(viewpoint_groups,
             _{world:"g7",
               candidates:[_{id:"zeta", type:"A", x:0, y:0, r_max:1},
                           _{id:"beta", type:"A", x:50, y:0, r_max:1},
                           _{id:"alpha", type:"A", x:0.5, y:0, r_max:1}],
               regions:[_{id:7, x:0, y:0, area_m2:3}, _{id:2, x:0, y:0, area_m2:1}]}, R),
    reply_groups(R, IMs),
    IMs == [0-["alpha", "zeta"], 1-["beta"], 2-[2], 3-[7]],
    candidate_group(g7, zeta, GZ), GZ == 0,
    candidate_group(g7, beta, GB), GB == 1,
    \+ candidate_group(g7, nope, _),
    findall(C-G, candidate_group(g7, C, G), CGs), CGs == [alpha-0, zeta-0, beta-1].
test(large_rmax_reaches_far, [nondet, cleanup(drop_world(g8))]) :-
    create_world(g8),
    %  s is first along x and small, b is 9 m further with R_max 10: the
    %  sweep from s must not stop before b
    replace_viewpoint_scene(g8, [vp_candidate(b, "t", 9, 0, 10), vp_candidate(s, "t", 0, 0, 0.1),
                                 vp_candidate(x1, "t", 4, 1, 0.1), vp_candidate(x2, "t", 5, 2, 0.1),
                                 vp_candidate(far, "t", 40, 0, 0.1)], [], 0),
    joinable(g8, s, b), \+ joinable(g8, s, x1),
    groups(g8, Gs),
    Gs == [0-objects-[b, s, x1, x2], 1-objects-[far]],
    %  the same scene spread along y
    replace_viewpoint_scene(g8, [vp_candidate(b, "t", 0, 9, 10), vp_candidate(s, "t", 0, 0, 0.1),
                                 vp_candidate(x1, "t", 1, 4, 0.1), vp_candidate(x2, "t", 2, 5, 0.1),
                                 vp_candidate(far, "t", 0, 40, 0.1)], [], 0),
    groups(g8, Gs2),
    Gs2 == Gs.
test(stores_floats, [nondet, cleanup(drop_world(g9))]) :-
    create_world(g9),
    replace_viewpoint_scene(g9, [vp_candidate(a, "mug", 1, 2, 3)], [unknown_region(scene, 4, 5, 6, 7)], 1),
    world_module(g9, M),
    M:vp_candidate(a, T, X, Y, R), T == "mug", X == 1.0, Y == 2.0, R == 3.0,
    M:unknown_region(scene, 4, RX, RY, RA), RX == 5.0, RY == 6.0, RA == 7.0,
    M:vp_min_area(A), A == 1.0.
test(empty_scene, [nondet, cleanup(drop_world(g10))]) :-
    fixture("g10"),
    call_api(viewpoint_groups, _{world:"g10", candidates:[], regions:[]}, R),
    R.result =@= _{groups:[], min_area_m2:0.5, steps:[]},
    scene_facts(g10, Fs), Fs == [vp_min_area(0.5)].
test(plan_steps_walk_the_plan, [nondet, cleanup(drop_world(g30))]) :-
    create_world(g30),
    Cs = [vp_candidate(a, "t", 0, 0, 1), vp_candidate(b, "t", 9, 0, 1)],
    replace_viewpoint_scene(g30, Cs, [], 0.5,
                            [vp_plan_step(0, 1, 8.0, 0.0, 0.0, 8.0, 5.0, 0.75, 25.0),
                             vp_plan_step(1, 0, 1.0, 0.0, 3.1, 7.0, 5.0, none, 47.5)]),
    findall(K-G, plan_step(g30, K, G, _, _), KGs), KGs == [0-1, 1-0],
    plan_step(g30, 0, _, pose(X, _, _), times(_, _, P, _)), X == 8.0, P == 0.75,
    %  a step naming a group the scene does not have: refused, nothing changes
    catch(( replace_viewpoint_scene(g30, Cs, [], 0.5,
                                    [vp_plan_step(0, 7, 0.0, 0.0, 0.0, 0.0, 0.0, none, 0.0)]),
            fail ),
          chizu_error(unknown_group(7), "steps[0].group_id"), true),
    findall(K, plan_step(g30, K, _, _, _), Ks), Ks == [0, 1],
    %  a new scene without steps drops the old plan
    replace_viewpoint_scene(g30, Cs, [], 0.5),
    \+ plan_step(g30, _, _, _, _).

		 /*******************************
		 *          REPLACING           *
		 *******************************/

test(replace_drops_previous_scene, [nondet, cleanup(drop_world(g11))]) :-
    fixture("g11"),
    call_api(viewpoint_groups,
             _{world:"g11", candidates:[_{id:"n1", type:"cup", x:0, y:0, r_max:2}],
               regions:[_{id:9, x:1, y:1, area_m2:4}]}, R),
    R.result.groups =@= [_{id:0, kind:"objects", members:["n1"]},
                        _{id:1, kind:"unknown", members:[9], area_m2:4.0}],
    world_module(g11, M),
    \+ M:vp_candidate(c1, _, _, _, _), \+ M:unknown_region(scene, 0, _, _, _),
    \+ observation_group(g11, 2, _, _), \+ joinable(g11, _, _),
    aggregate_all(count, M:vp_group(_, _, _), 2),
    aggregate_all(count, M:vp_min_area(_), 1).
chizu_error_term(chizu_error(_)).
chizu_error_term(chizu_error(_, _)).

test(module_duplicates_and_bad_terms, [nondet, cleanup(drop_world(g12))]) :-
    fixture("g12"), scene_facts(g12, Before),
    catch(( replace_viewpoint_scene(g12, [vp_candidate(a, "t", 0, 0, 1), vp_candidate(b, "t", 0, 0, 1),
                                          vp_candidate(a, "t", 1, 1, 1)], [], 0), fail ),
          chizu_error(duplicate_candidate(a), "candidates[2].id"), true),
    catch(( replace_viewpoint_scene(g12, [], [unknown_region(scene, 3, 0, 0, 1), unknown_region(scene, 3, 0, 0, 1)], 0), fail ),
          chizu_error(duplicate_region(3), "regions[1].id"), true),
    forall(member(Cs-Rs-A, [ [vp_candidate(a, t, 0, 0, 1)]-[]-0,
                             [vp_candidate('A', "t", 0, 0, 1)]-[]-0,
                             [vp_candidate(a, "t", 0, 0, 0)]-[]-0,
                             [vp_candidate(a, "t", x, 0, 1)]-[]-0,
                             [vp_candidate(a, "t", 1.0e16, 0, 1)]-[]-0,
                             [vp_candidate(a, "", 0, 0, 1)]-[]-0,
                             [_]-[]-0,
                             []-[unknown_region(scene, -1, 0, 0, 1)]-0,
                             []-[unknown_region(scene, 1, 0, 0, -1)]-0,
                             []-[vp_candidate(a, "t", 0, 0, 1)]-0,
                             []-[]-(-1),
                             []-[]-inf,
                             nolist-[]-0 ]),
           catch(( replace_viewpoint_scene(g12, Cs, Rs, A), fail ), E, chizu_error_term(E))),
    catch(( replace_viewpoint_scene(g12, [], [], -1), fail ),
          chizu_error(invalid_number(-1), "min_area_m2"), true),
    scene_facts(g12, After), After == Before.
test(worlds_do_not_share, [nondet, cleanup((drop_world(g13), drop_world(g14)))]) :-
    fixture("g13"), new_world("g14"),
    \+ observation_group(g14, _, _, _), \+ joinable(g14, _, _),
    observation_group(g13, 0, objects, _).
test(fact_kinds_registered, [true(Ks == [vp_candidate/5, vp_group/3, vp_min_area/1,
                                         vp_plan_step/9])]) :-
    findall(K, grouping_fact(K), Ks0), msort(Ks0, Ks),
    forall(member(K, Ks), world_fact(K)).

		 /*******************************
		 *          API ERRORS          *
		 *******************************/

test(bad_candidate_numbers, [nondet, cleanup(drop_world(g15))]) :-
    fixture("g15"), scene_facts(g15, Before),
    bad_candidate(g15, 0, x, "1", E1), error_is(E1, "invalid_number", "candidates[0].x"),
    E1.value == "1",
    bad_candidate(g15, 2, y, null, E2), error_is(E2, "invalid_number", "candidates[2].y"),
    bad_candidate(g15, 1, r_max, -1, E3), error_is(E3, "invalid_number", "candidates[1].r_max"),
    E3.value == -1,
    bad_candidate(g15, 4, r_max, 0, E4), error_is(E4, "invalid_number", "candidates[4].r_max"),
    bad_candidate(g15, 4, r_max, 0.0, E5), error_is(E5, "invalid_number", "candidates[4].r_max"),
    bad_candidate(g15, 3, x, 1.0e300, E6), error_is(E6, "invalid_number", "candidates[3].x"),
    bad_candidate(g15, 0, r_max, [1], E7), error_is(E7, "invalid_number", "candidates[0].r_max"),
    scene_facts(g15, After), After == Before.
test(bad_candidate_ids, [nondet, cleanup(drop_world(g16))]) :-
    fixture("g16"), scene_facts(g16, Before),
    bad_candidate(g16, 1, id, "Bad-Id", E1), error_is(E1, "invalid_id", "candidates[1].id"),
    E1.value == "Bad-Id",
    bad_candidate(g16, 0, id, "c1'), assertz(pwned), ('", E2),
    error_is(E2, "invalid_id", "candidates[0].id"),
    bad_candidate(g16, 0, id, 7, E3), error_is(E3, "invalid_id", "candidates[0].id"),
    bad_candidate(g16, 3, id, "c2", E4), error_is(E4, "duplicate_candidate", "candidates[3].id"),
    E4.value == "c2",
    \+ catch(user:pwned, _, fail),
    scene_facts(g16, After), After == Before.
test(bad_candidate_shape_and_type, [nondet, cleanup(drop_world(g17))]) :-
    fixture("g17"), scene_facts(g17, Before),
    bad_candidate(g17, 3, x, '$del', E1), error_is(E1, "missing", "candidates[3].x"),
    E1.value == "x",
    bad_candidate(g17, 0, r_max, '$del', E2), error_is(E2, "missing", "candidates[0].r_max"),
    length(L65, 65), maplist(=(0'a), L65), string_codes(Long, L65),
    bad_candidate(g17, 2, type, Long, E3), error_is(E3, "invalid_type", "candidates[2].type"),
    length(L64, 64), maplist(=(0'a), L64), string_codes(Ok64, L64),
    candidates(Cs0), Cs0 = [C0|CsR], scene_args("g17", A0),
    call_api(viewpoint_groups, A0.put(candidates, [C0.put(type, Ok64)|CsR]), ROk), ROk.ok == true,
    scene_facts(g17, Before64),
    bad_candidate(g17, 2, type, 3, E4), error_is(E4, "invalid_type", "candidates[2].type"),
    bad_candidate(g17, 2, type, "", E5), error_is(E5, "invalid_type", "candidates[2].type"),
    bad_candidate(g17, 2, type, ["A"], E6), error_is(E6, "invalid_type", "candidates[2].type"),
    bad_scene(g17, candidates, _{id:"c1"}, E7), error_is(E7, "invalid_list", "candidates"),
    bad_scene(g17, candidates, [["c1", "A", 0, 0, 1]], E8),
    error_is(E8, "invalid_candidate", "candidates[0]"),
    scene_args("g17", A1), del_dict(candidates, A1, _, A2),
    call_api(viewpoint_groups, A2, R9), error_is(R9.error, "missing", "candidates"),
    scene_facts(g17, After), After == Before64, Before \== Before64.
test(bad_regions, [nondet, cleanup(drop_world(g18))]) :-
    fixture("g18"), scene_facts(g18, Before),
    bad_region(g18, 1, id, -1, E1), error_is(E1, "invalid_region_id", "regions[1].id"),
    E1.value == -1,
    bad_region(g18, 0, id, 1.0, E2), error_is(E2, "invalid_region_id", "regions[0].id"),
    bad_region(g18, 0, id, "0", E3), error_is(E3, "invalid_region_id", "regions[0].id"),
    bad_region(g18, 2, id, 0, E4), error_is(E4, "duplicate_region", "regions[2].id"),
    E4.value == 0,
    bad_region(g18, 2, area_m2, -0.5, E5), error_is(E5, "invalid_number", "regions[2].area_m2"),
    bad_region(g18, 1, x, "a", E6), error_is(E6, "invalid_number", "regions[1].x"),
    bad_region(g18, 1, y, '$del', E7), error_is(E7, "missing", "regions[1].y"),
    bad_scene(g18, regions, [3], E8), error_is(E8, "invalid_region", "regions[0]"),
    bad_scene(g18, regions, "none", E9), error_is(E9, "invalid_list", "regions"),
    scene_facts(g18, After), After == Before.
test(bad_min_area, [nondet, cleanup(drop_world(g19))]) :-
    fixture("g19"), scene_facts(g19, Before),
    bad_scene(g19, min_area_m2, -0.1, E1), error_is(E1, "invalid_number", "min_area_m2"),
    bad_scene(g19, min_area_m2, "0.5", E2), error_is(E2, "invalid_number", "min_area_m2"),
    bad_scene(g19, min_area_m2, [], E3), error_is(E3, "invalid_number", "min_area_m2"),
    scene_facts(g19, After), After == Before.
test(unknown_world, [nondet]) :-
    scene_args("nope", Args), call_api(viewpoint_groups, Args, R),
    error_is(R.error, "unknown_world", "world"),
    scene_args("x), halt, (", Args2), call_api(viewpoint_groups, Args2, R2),
    error_is(R2.error, "invalid_id", "world"),
    call_api(viewpoint_scene, _{world:"nope"}, R3), error_is(R3.error, "unknown_world", "world"),
    call_api(viewpoint_scene, _{}, R4), error_is(R4.error, "missing", "world").

		 /*******************************
		 *        READING A SCENE       *
		 *******************************/

test(scene_of_empty_world, [nondet, cleanup(drop_world(g20))]) :-
    new_world("g20"),
    call_api(viewpoint_scene, _{world:"g20"}, R),
    R.ok == true, R.result =@= _{groups:[], min_area_m2:0.5, steps:[]}.
test(scene_reads_stored_groups, [nondet, cleanup(drop_world(g21))]) :-
    fixture("g21", R0),
    scene_args("g21", A0), call_api(viewpoint_groups, A0.put(min_area_m2, 1.5), R1),
    call_api(viewpoint_scene, _{world:"g21"}, R2),
    R2.result =@= R1.result, R2.result \=@= R0.result,
    R2.result.min_area_m2 =:= 1.5.
test(facts_op_lists_them, [nondet, cleanup(drop_world(g22))]) :-
    fixture("g22"), call_api(facts, _{world:"g22"}, R),
    memberchk("vp_candidate(c3,\"mug\",3.2,0.0,1.0)", R.result),
    memberchk("unknown_region(scene,1,5.0,5.0,0.3)", R.result),
    memberchk("vp_group(0,objects,[c1,c2,c3])", R.result),
    memberchk("vp_group(4,unknown,[2])", R.result),
    memberchk("vp_min_area(0.5)", R.result).
test(ops_listed, [nondet]) :-
    operation(viewpoint_groups), operation(viewpoint_scene).

		 /*******************************
		 *            QUERY             *
		 *******************************/

test(query_whitelist, [nondet, cleanup(drop_world(g23))]) :-
    fixture("g23"),
    world_query(g23, "observation_group(G, K, Ms)", 10, Sols, false),
    length(Sols, 5), Sols = [S0|_],
    S0.'G' == 0, S0.'K' == "objects", S0.'Ms' == ["c1", "c2", "c3"],
    world_query(g23, "same_group(c1, X)", 10, S2, false),
    findall(X, member(_{'X':X}, S2), Xs), msort(Xs, ["c1", "c2", "c3"]),
    world_query(g23, "joinable(c1, X)", 10, [S3], false), S3.'X' == "c2",
    world_query(g23, "candidate_group(c5, G)", 10, [S4], false), S4.'G' == 2,
    world_query(g23, "unknown_group_area(G, A), A < 1", 10, [S5], false),
    S5.'G' == 4, S5.'A' =:= 0.5,
    world_query(g23, "vp_candidate(c3, T, X, _, _), unknown_region(scene, 1, _, _, A)", 10, [S6], false),
    S6.'T' == "mug", S6.'X' =:= 3.2, S6.'A' =:= 0.3,
    world_query(g23, "\\+ same_group(c4, c5)", 10, [_], false),
    catch(( world_query(g23, "replace_viewpoint_scene(g23, [], [], 0)", 5, _, _), fail ),
          chizu_error(not_allowed(replace_viewpoint_scene/4), goal), true),
    catch(( world_query(g23, "grouping:joinable(g23, A, B)", 5, _, _), fail ),
          chizu_error(not_allowed(_), goal), true).
test(query_op, [nondet, cleanup(drop_world(g24))]) :-
    fixture("g24"),
    call_api(query, _{world:"g24", goal:"same_group(c1, c3), candidate_group(c3, G)",
                      max_solutions:5}, R),
    R.result =@= _{solutions:[_{'G':0}], truncated:false},
    call_api(query, _{world:"g24", goal:"observation_group(G, \"unknown\", _)",
                      max_solutions:5}, R2),
    R2.result.solutions == [],
    call_api(query, _{world:"g24", goal:"observation_group(G, unknown, [R])",
                      max_solutions:1}, R3),
    R3.result =@= _{solutions:[_{'G':3, 'R':0}], truncated:true}.

		 /*******************************
		 *            LARGER            *
		 *******************************/

random_candidate(I, _{id:Id, type:"obj", x:X, y:Y, r_max:R}) :-
    format(string(Id), "c~d", [I]),
    random_between(0, 100000, XI), X is XI / 1000,
    random_between(0, 100000, YI), Y is YI / 1000,
    random_between(200, 3000, RI), R is RI / 1000.

%   Partition check: every candidate is in exactly one group, joinable
%   candidates share it, and each group is connected under joinable/3.
consistent_groups(W, N) :-
    findall(C, ( observation_group(W, _, objects, Ms), member(C, Ms) ), All),
    length(All, N), sort(All, Set), length(Set, N),
    forall(joinable(W, A, B), same_group(W, A, B)),
    forall(observation_group(W, _, objects, [M0|Ms]),
           ( connected_from([M0], W, [M0], Reached), msort([M0|Ms], Reached) )).

connected_from([], _, Seen, Seen).
connected_from([A|As], W, Seen0, Seen) :-
    findall(B, ( joinable(W, A, B), \+ memberchk(B, Seen0) ), Bs0), sort(Bs0, Bs),
    ord_union(Seen0, Bs, Seen1),
    append(As, Bs, Next),
    connected_from(Next, W, Seen1, Seen).

test(random_scene_300, [nondet, cleanup(drop_world(g25))]) :-
    new_world("g25"),
    set_random(seed(2024)),
    numlist(1, 300, Is), maplist(random_candidate, Is, Cs),
    call_api(viewpoint_groups, _{world:"g25", candidates:Cs, regions:[]}, R),
    R.ok == true,
    length(R.result.groups, NG), NG > 1, NG < 300,
    consistent_groups(g25, 300).
candidate_term(D, vp_candidate(A, "t", X, Y, R)) :-
    get_dict(id, D, Id), atom_string(A, Id),
    get_dict(x, D, X), get_dict(y, D, Y), get_dict(r_max, D, R).

test(random_scenes_match_naive_closure, [nondet, cleanup(drop_world(g26))]) :-
    create_world(g26),
    set_random(seed(7)),
    forall(between(1, 5, _),
           ( numlist(1, 40, Is), maplist(random_candidate, Is, Ds),
             maplist(candidate_term, Ds, Cs),
             replace_viewpoint_scene(g26, Cs, [], 0),
             consistent_groups(g26, 40) )).

:- end_tests(grouping).
