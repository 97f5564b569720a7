/*  The SLAM map facts, their rules and the slam_* api ops.

    Fixture (run r1a, metres): poses (0,0) -> (3,4) -> (3,8), path 5 + 4 = 9;
    free 60 m2, occupied 20 m2, unknown 20 m2 (explored 0.8);
    unknown regions 0 at (1,1) 2.0 m2, 1 at (10,0) 5.5 m2, 2 at (0,3) 1.0 m2;
    loop closures scan 0 -> 40 (score 0.8) and 12 -> 90 (score 1).
*/
:- begin_tests(slam).
:- use_module(library(http/json)).
:- use_module(world).
:- use_module(slam).
:- use_module(query).
:- use_module(api).

call_api(Op, Args, Reply) :-
    atom_json_dict(In, _{op:Op, args:Args, time_limit_s:5, inference_limit:10000000}, []),
    handle(In, Out),
    atom_json_dict(Out, Reply, []).

slam_args(W, _{world:W, run:"r1a", poses:Ps, info:Info, regions:Rs, closures:Cs}) :-
    Ps = [[0, 0, 0], [3, 4, 0.5], [3.0, 8, 1.0]],
    Info = _{resolution_m:0.05, free_m2:60, occupied_m2:20.0, unknown_m2:20},
    Rs = [_{x:1, y:1, area_m2:2.0}, _{x:10, y:0, area_m2:5.5}, _{x:0, y:3, area_m2:1}],
    Cs = [[0, 40, 0.8], [12, 90, 1]].

%   A world with the fixture, built through the api ops.
fixture(W) :-
    call_api(create_world, _{world:W, landmarks:[]}, R0), R0.ok == true,
    slam_args(W, Args),
    call_api(slam_facts, Args, R), R.ok == true.

%   A slam_facts call with one field replaced; Err is the error.
bad_facts(W, Key, Value, Err) :-
    slam_args(W, Args0), put_dict(Key, Args0, Value, Args),
    call_api(slam_facts, Args, R),
    R.ok == false, Err = R.error.

slam_facts_of(W, Fs) :-
    world_module(W, M),
    findall(F, ( slam_fact(N/A), functor(F, N, A), M:F ), Fs).

close_to(X, Y) :- abs(X - Y) < 1.0e-9.

		 /*******************************
		 *         REPLACE FACTS        *
		 *******************************/

test(replace_stores_floats, [nondet, cleanup(drop_world(s1))]) :-
    create_world(s1),
    replace_slam_facts(s1, [committed_map(r2), map_info(r2, 0.1, 1, 2, 3),
                            map_pose(r2, 0, 1, 2, 0), unknown_region(r2, 0, 4, 5, 6),
                            loop_closure(r2, 3, 7, 1), loop_closure(r2, 0, 7, 0)]),
    world_module(s1, M),
    M:map_info(r2, R, F, O, U), R == 0.1, F == 1.0, O == 2.0, U == 3.0,
    M:map_pose(r2, 0, X, Y, T), X == 1.0, Y == 2.0, T == 0.0,
    M:committed_map(C), C == r2,
    M:loop_closure(r2, 3, 7, S1), S1 == 1.0,
    M:loop_closure(r2, 0, 7, S0), S0 == 0.0.
test(replace_is_atomic, [nondet, cleanup(drop_world(s2))]) :-
    fixture(s2), slam_facts_of(s2, Before), Before \== [],
    forall(member(Bad, [ [committed_map(r2), map_info(r2, 0, 0, 0, 0), map_pose(r2, -1, 0, 0, 0)],
                         [committed_map(r2), map_info(r2, 0, 0, 0, 0), map_pose(r2, 0, a, 0, 0)],
                         [committed_map(r2), map_info(r2, 0, -1, 0, 0)],
                         [committed_map('R2'), map_info('R2', 0, 0, 0, 0)],
                         [committed_map("r2"), map_info("r2", 0, 0, 0, 0)],
                         [committed_map(r2), map_info(r2, 0, 0, 0, 0), eig_point(0, 0, 0)],
                         [committed_map(r2), committed_map(r3),
                          map_info(r2, 0, 0, 0, 0), map_info(r3, 0, 0, 0, 0)],
                         [committed_map(r2)],
                         [committed_map(r2), map_info(r2, 0, 0, 0, 0),
                          unknown_region(r2, 0, 0, 0, 1), unknown_region(r2, 0, 1, 1, 1)],
                         [committed_map(r2), map_info(r2, 0, 0, 0, 0), _],
                         [committed_map(r2), map_info(r2, 0, 0, 0, 0), loop_closure(r2, 5, 3, 0.5)],
                         [committed_map(r2), map_info(r2, 0, 0, 0, 0), loop_closure(r2, 3, 3, 0.5)],
                         [committed_map(r2), map_info(r2, 0, 0, 0, 0), loop_closure(r2, -1, 3, 0.5)],
                         [committed_map(r2), map_info(r2, 0, 0, 0, 0), loop_closure(r2, 1.0, 3, 0.5)],
                         [committed_map(r2), map_info(r2, 0, 0, 0, 0), loop_closure(r2, 1, 3, 1.5)],
                         [committed_map(r2), map_info(r2, 0, 0, 0, 0), loop_closure(r2, 1, 3, -0.1)],
                         [committed_map(r2), map_info(r2, 0, 0, 0, 0), loop_closure(r2, 1, 3, nan)],
                         [committed_map(r2), map_info(r2, 0, 0, 0, 0), loop_closure(r2, 1, 3, x)],
                         [committed_map(r2), map_info(r2, 0, 0, 0, 0), loop_closure("r2", 1, 3, 0.5)],
                         [committed_map(r2), map_info(r2, 0, 0, 0, 0), loop_closure(r2, 1, 3)],
                         [committed_map(r2), map_info(r2, 0, 0, 0, 0),
                          loop_closure(r2, 1, 3, 0.5), loop_closure(r2, 1, 3, 0.7)],
                         not_a_list ]),
           catch(( replace_slam_facts(s2, Bad), fail ), chizu_error(_), true)),
    slam_facts_of(s2, After),
    After == Before.
test(replace_drops_previous_run, [nondet, cleanup(drop_world(s3))]) :-
    fixture(s3),
    replace_slam_facts(s3, [committed_map(rbeef), map_info(rbeef, 0.1, 1, 1, 0),
                            map_pose(rbeef, 0, 0, 0, 0)]),
    world_module(s3, M),
    \+ M:map_pose(r1a, _, _, _, _), \+ M:unknown_region(_, _, _, _, _),
    \+ M:map_info(r1a, _, _, _, _), \+ M:committed_map(r1a),
    \+ M:loop_closure(_, _, _, _),
    M:committed_map(rbeef),
    loop_closure_count(s3, N), N == 0, \+ closes_loop(s3, _, _),
    explored_fraction(s3, F), F =:= 1.0,
    map_path_length(s3, L), L == 0.0,
    \+ largest_unknown_region(s3, _, _).
test(worlds_do_not_share, [nondet, cleanup((drop_world(s4), drop_world(s5)))]) :-
    fixture(s4), create_world(s5),
    \+ explored_fraction(s5, _), \+ map_path_length(s5, _),
    explored_fraction(s4, _).
test(slam_fact_kinds, [true(Ks == [committed_map/1, loop_closure/4, map_info/5, map_pose/5,
                                     unknown_region/5])]) :-
    findall(K, slam_fact(K), Ks0), msort(Ks0, Ks),
    forall(member(K, Ks), world_fact(K)).
test(run_ids, [nondet]) :-
    valid_run_id(r0), valid_run_id("r3f9a"), valid_run_id('rdeadbeef'),
    \+ valid_run_id(r), \+ valid_run_id('R1'), \+ valid_run_id("r1; halt"),
    \+ valid_run_id("r1G"), \+ valid_run_id(1), \+ valid_run_id("x1"),
    length(L65, 65), maplist(=(0'a), L65), atom_codes(Long, [0'r|L65]),
    \+ valid_run_id(Long).

		 /*******************************
		 *            RULES             *
		 *******************************/

test(explored_fraction_value, [nondet, cleanup(drop_world(s6))]) :-
    fixture(s6), explored_fraction(s6, F), close_to(F, 0.8).
test(explored_fraction_empty_total, [nondet, cleanup(drop_world(s7))]) :-
    create_world(s7),
    \+ explored_fraction(s7, _),
    replace_slam_facts(s7, [committed_map(r7), map_info(r7, 0.05, 0, 0, 0)]),
    explored_fraction(s7, F), F == 0.0.
test(region_within, [nondet, cleanup(drop_world(s8))]) :-
    fixture(s8),
    findall(Id-D, unknown_region_within(s8, 0, 0, 4, Id, D), Ps),
    Ps = [0-D0, 2-D2], close_to(D0, sqrt(2)), close_to(D2, 3.0),
    findall(Id, unknown_region_within(s8, 0, 0, 100, Id, _), [0, 1, 2]),
    \+ unknown_region_within(s8, 0, 0, 1.0, _, _),
    unknown_region_within(s8, 10, 0, 0, 1, D1), D1 =:= 0,
    catch(( unknown_region_within(s8, a, 0, 1, _, _), fail ),
          chizu_error(invalid_number(a), x), true).
test(largest_region, [nondet, cleanup(drop_world(s9)), true(Id-A == 1-5.5)]) :-
    fixture(s9), largest_unknown_region(s9, Id, A).
test(largest_region_tie_lowest_id, [nondet, cleanup(drop_world(s10)), true(Id == 1)]) :-
    create_world(s10),
    replace_slam_facts(s10, [committed_map(r1), map_info(r1, 1, 1, 1, 1),
                             unknown_region(r1, 3, 0, 0, 2.0), unknown_region(r1, 1, 0, 0, 2),
                             unknown_region(r1, 0, 0, 0, 1)]),
    largest_unknown_region(s10, Id, _).
test(path_length, [nondet, cleanup(drop_world(s11))]) :-
    fixture(s11), map_path_length(s11, L), close_to(L, 9.0),
    replace_slam_facts(s11, [committed_map(r1), map_info(r1, 1, 1, 1, 1),
                             map_pose(r1, 2, 3, 4, 0), map_pose(r1, 0, 0, 0, 0),
                             map_pose(r1, 1, 3, 0, 0)]),
    map_path_length(s11, L2), close_to(L2, 7.0).
test(loop_closures, [nondet, cleanup(drop_world(s24))]) :-
    fixture(s24),
    loop_closure_count(s24, N), N == 2,
    findall(A-B, closes_loop(s24, A, B), [0-40, 12-90]),
    closes_loop(s24, 12, 90), \+ closes_loop(s24, 40, 0), \+ closes_loop(s24, 0, 90),
    findall(B, closes_loop(s24, 0, B), [40]).
test(loop_closures_of_committed_run_only, [nondet, cleanup(drop_world(s25))]) :-
    create_world(s25),
    \+ loop_closure_count(s25, _), \+ closes_loop(s25, _, _),
    replace_slam_facts(s25, [committed_map(r1), map_info(r1, 1, 1, 1, 1),
                             loop_closure(r1, 2, 9, 0.7),
                             loop_closure(r2, 0, 5, 0.9), loop_closure(r2, 1, 5, 0.9)]),
    loop_closure_count(s25, N), N == 1,
    findall(A-B, closes_loop(s25, A, B), [2-9]).

		 /*******************************
		 *             API              *
		 *******************************/

test(facts_reply, [nondet, cleanup(drop_world(s12))]) :-
    call_api(create_world, _{world:"s12", landmarks:[]}, _),
    slam_args("s12", Args), call_api(slam_facts, Args, R),
    R.result = _{world:"s12", run:"r1a", poses:3, regions:3, closures:2},
    world_module(s12, M), M:map_pose(r1a, 2, 3.0, 8.0, 1.0),
    M:unknown_region(r1a, 2, 0.0, 3.0, 1.0),
    M:loop_closure(r1a, 0, 40, 0.8), M:loop_closure(r1a, 12, 90, 1.0).
test(facts_closures_optional, [nondet, cleanup(drop_world(s26))]) :-
    fixture(s26), loop_closure_count(s26, 2),
    slam_args("s26", A0), del_dict(closures, A0, _, A1),
    call_api(slam_facts, A1, R), R.ok == true, R.result.closures == 0,
    world_module(s26, M), \+ M:loop_closure(_, _, _, _),
    loop_closure_count(s26, N), N == 0,
    call_api(slam_facts, A0.put(closures, []), R2), R2.result.closures == 0.
test(facts_bad_closures, [nondet, cleanup(drop_world(s27))]) :-
    fixture(s27), slam_facts_of(s27, Before),
    memberchk(loop_closure(r1a, 0, 40, _), Before),
    bad_facts(s27, closures, [[0, 4, 0.5], [5, 3, 0.5]], E1),
    E1.type == "unordered_closure", E1.field == "closures[1]",
    bad_facts(s27, closures, [[3, 3, 0.5]], E2),
    E2.type == "unordered_closure", E2.field == "closures[0]",
    bad_facts(s27, closures, [[0, 4, 0.5], [1, 5, 0.5], [0, 1, 2.0]], E3),
    E3.type == "invalid_score", E3.field == "closures[2]", E3.value =:= 2.0,
    bad_facts(s27, closures, [[0, 1, -0.5]], E4),
    E4.type == "invalid_score", E4.field == "closures[0]",
    bad_facts(s27, closures, [[0, 1, "0.5"]], E5),
    E5.type == "invalid_number", E5.field == "closures[0]",
    bad_facts(s27, closures, [[-1, 1, 0.5]], E6),
    E6.type == "invalid_index", E6.field == "closures[0]",
    bad_facts(s27, closures, [[0, 1.0, 0.5]], E7),
    E7.type == "invalid_index", E7.field == "closures[0]",
    bad_facts(s27, closures, [[0, "r1; halt", 0.5]], E8),
    E8.type == "invalid_index", E8.field == "closures[0]",
    bad_facts(s27, closures, [[0, 1]], E9),
    E9.type == "invalid_closure", E9.field == "closures[0]",
    bad_facts(s27, closures, [_{a:0, b:1, score:0.5}], E10),
    E10.type == "invalid_closure", E10.field == "closures[0]",
    bad_facts(s27, closures, _{a:0}, E11),
    E11.type == "invalid_list", E11.field == "closures",
    bad_facts(s27, closures, [[0, 1, 0.5], [0, 1, 0.6]], E12),
    E12.type == "inconsistent_facts",
    slam_facts_of(s27, After), After == Before.
test(facts_bad_run_id, [nondet, cleanup(drop_world(s13))]) :-
    fixture(s13), slam_facts_of(s13, Before),
    forall(member(Bad, ["r1; halt", "R1", "r", "r1), assertz(pwned), (r1", 12, "rABC"]),
           ( bad_facts(s13, run, Bad, E),
             E.type == "invalid_run_id", E.field == "run" )),
    bad_facts(s13, run, "r1; halt", E1), E1.value == "r1; halt",
    slam_args(s13, A0), del_dict(run, A0, _, A1), call_api(slam_facts, A1, R2),
    R2.error.type == "missing", R2.error.field == "run",
    slam_facts_of(s13, After), After == Before,
    \+ catch(user:pwned, _, fail).
test(facts_bad_poses, [nondet, cleanup(drop_world(s14))]) :-
    fixture(s14), slam_facts_of(s14, Before),
    bad_facts(s14, poses, [[0, 0, 0], [1, 2]], E1),
    E1.type == "invalid_pose", E1.field == "poses[1]",
    bad_facts(s14, poses, [[0, "1", 0]], E2),
    E2.type == "invalid_number", E2.field == "poses[0]",
    bad_facts(s14, poses, _{x:1}, E3),
    E3.type == "invalid_list", E3.field == "poses",
    bad_facts(s14, poses, [_{x:0, y:0, th:0}], E4),
    E4.type == "invalid_pose",
    slam_facts_of(s14, After), After == Before.
test(facts_bad_info_and_regions, [nondet, cleanup(drop_world(s15))]) :-
    fixture(s15), slam_facts_of(s15, Before),
    bad_facts(s15, info, [1, 2, 3, 4], E1),
    E1.type == "invalid_info", E1.field == "info",
    bad_facts(s15, info, _{resolution_m:0.05, free_m2:1, occupied_m2: -1, unknown_m2:0}, E2),
    E2.type == "invalid_number", E2.field == "info.occupied_m2",
    bad_facts(s15, info, _{resolution_m:0.05, free_m2:1, occupied_m2:1}, E3),
    E3.type == "missing", E3.field == "info.unknown_m2",
    bad_facts(s15, regions, [_{x:0, y:0, area_m2:1}, [0, 0, 1]], E4),
    E4.type == "invalid_region", E4.field == "regions[1]",
    bad_facts(s15, regions, [_{x:0, y:"0", area_m2:1}], E5),
    E5.type == "invalid_number", E5.field == "regions[0].y",
    bad_facts(s15, regions, [_{x:0, y:0, area_m2: -2}], E6),
    E6.type == "invalid_number", E6.field == "regions[0].area_m2",
    bad_facts(s15, regions, [_{x:0, y:0}], E7),
    E7.type == "missing", E7.field == "regions[0].area_m2",
    slam_facts_of(s15, After), After == Before.
test(facts_unknown_world, [nondet]) :-
    slam_args("nope", Args), call_api(slam_facts, Args, R),
    R.error.type == "unknown_world", R.error.field == "world",
    slam_args("x), halt, (", Args2), call_api(slam_facts, Args2, R2),
    R2.error.type == "invalid_id", R2.error.field == "world".
test(summary_op, [nondet, cleanup(drop_world(s16))]) :-
    fixture(s16),
    call_api(slam_summary, _{world:"s16"}, R), R.ok == true,
    S = R.result,
    S.run == "r1a", close_to(S.explored_fraction, 0.8), close_to(S.path_length_m, 9.0),
    S.resolution_m =:= 0.05, S.free_m2 =:= 60, S.occupied_m2 =:= 20, S.unknown_m2 =:= 20,
    S.loop_closures == 2,
    S.regions = [G0, G1, G2],
    G0 = _{id:0, x:1.0, y:1.0, area_m2:2.0},
    G1.id == 1, G2.id == 2, G2.area_m2 =:= 1.
test(summary_without_map, [nondet, cleanup(drop_world(s17))]) :-
    call_api(create_world, _{world:"s17", landmarks:[]}, _),
    call_api(slam_summary, _{world:"s17"}, R),
    R.ok == false, R.error.type == "unknown_map", R.error.field == "map",
    R.error.value == "s17",
    call_api(slam_summary, _{world:"nope"}, R2), R2.error.type == "unknown_world".
test(regions_near_sorted, [nondet, cleanup(drop_world(s19))]) :-
    fixture(s19),
    call_api(slam_regions_near, _{world:"s19", x:0, y:0, radius:4}, R),
    R.result = [A, B],
    A.id == 0, close_to(A.distance, sqrt(2)), A.area_m2 =:= 2,
    B.id == 2, close_to(B.distance, 3.0), B.x =:= 0, B.y =:= 3,
    call_api(slam_regions_near, _{world:"s19", x:10, y:10, radius:1}, R2), R2.result == [],
    call_api(slam_regions_near, _{world:"s19", x:0, y:0, radius: -1}, R3),
    R3.error.type == "invalid_radius", R3.error.field == "radius",
    call_api(slam_regions_near, _{world:"s19", x:"0", y:0, radius:1}, R4),
    R4.error.type == "invalid_number", R4.error.field == "x",
    call_api(slam_regions_near, _{world:"s19", x:0, y:0}, R5),
    R5.error.type == "missing", R5.error.field == "radius".
test(regions_near_without_map, [nondet, cleanup(drop_world(s20))]) :-
    call_api(create_world, _{world:"s20", landmarks:[]}, _),
    call_api(slam_regions_near, _{world:"s20", x:0, y:0, radius:1}, R),
    R.error.type == "unknown_map".
test(facts_op_lists_them, [nondet, cleanup(drop_world(s21))]) :-
    fixture(s21), call_api(facts, _{world:"s21"}, R),
    memberchk("committed_map(r1a)", R.result),
    memberchk("map_info(r1a,0.05,60.0,20.0,20.0)", R.result),
    memberchk("map_pose(r1a,1,3.0,4.0,0.5)", R.result),
    memberchk("unknown_region(r1a,1,10.0,0.0,5.5)", R.result),
    memberchk("loop_closure(r1a,12,90,1.0)", R.result).
test(ops_listed, [nondet]) :-
    forall(member(Op, [slam_facts, slam_summary, slam_regions_near]), operation(Op)).

		 /*******************************
		 *        QUERY AND REPL        *
		 *******************************/

test(query_whitelist, [nondet, cleanup(drop_world(s22))]) :-
    fixture(s22),
    world_query(s22, "explored_fraction(F), map_path_length(L)", 5, [S1], false),
    close_to(S1.'F', 0.8), close_to(S1.'L', 9.0),
    world_query(s22, "largest_unknown_region(Id, A)", 5, [S2], false),
    S2.'Id' == 1, S2.'A' =:= 5.5,
    world_query(s22, "unknown_region_within(0, 0, 4, Id, D)", 5, [_, _], false),
    world_query(s22, "committed_map(R), map_info(R, Res, _, _, _)", 5, [S3], false),
    S3.'R' == "r1a", S3.'Res' =:= 0.05,
    world_query(s22, "map_pose(_, I, _, _, _)", 2, [_, _], true),
    world_query(s22, "unknown_region(_, 2, X, Y, _)", 5, [S4], false),
    S4.'X' =:= 0, S4.'Y' =:= 3,
    world_query(s22, "loop_closure(R, 0, B, S)", 5, [S5], false),
    S5.'R' == "r1a", S5.'B' == 40, close_to(S5.'S', 0.8),
    world_query(s22, "loop_closure_count(N)", 5, [S6], false), S6.'N' == 2,
    world_query(s22, "closes_loop(A, B), A > 5", 5, [S7], false),
    S7.'A' == 12, S7.'B' == 90,
    catch(( world_query(s22, "map_path_length(L), assertz(pwned)", 5, _, _), fail ),
          chizu_error(not_allowed(assertz/1), goal), true),
    catch(( world_query(s22, "replace_slam_facts(s22, [])", 5, _, _), fail ),
          chizu_error(not_allowed(replace_slam_facts/2), goal), true),
    \+ catch(user:pwned, _, fail).
test(repl_helpers, [nondet, cleanup(drop_world(s23))]) :-
    fixture(s23),
    repl:use_world(s23),
    repl:explored_fraction(F), close_to(F, 0.8),
    repl:largest_unknown_region(Id, A), Id == 1, A =:= 5.5,
    findall(I, repl:unknown_region_within(0, 0, 4, I, _), [0, 2]),
    repl:map_path_length(L), close_to(L, 9.0),
    repl:loop_closure_count(N), N == 2,
    findall(SA-SB, repl:closes_loop(SA, SB), [0-40, 12-90]).

:- end_tests(slam).
