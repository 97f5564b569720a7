/*  The JSON entry point: whitelisted operations, validated ids, limits, atomicity. */
:- begin_tests(api).
:- use_module(library(http/json)).
:- use_module(api).
:- use_module(world).

call_api(Op, Args, Reply) :- call_api(Op, Args, 5, 10000000, Reply).
call_api(Op, Args, T, N, Reply) :-
    atom_json_dict(In, _{op:Op, args:Args, time_limit_s:T, inference_limit:N}, []),
    handle(In, Out),
    atom_json_dict(Out, Reply, []).

mk(W) :- call_api(create_world, _{world:W, landmarks:["a", "b", "c"]}, R), R.ok == true.

test(batch_runs_in_order_and_names_a_bad_call, [nondet, cleanup(drop_world(api9))]) :-
    mk(api9),
    Reach = _{world:"api9", from:"a", to:"b"},
    call_api(batch, _{calls:[_{op:"reached", args:Reach}, _{op:"reached", args:Reach}]}, R),
    R.ok == true, R.result = [_, Second], Second.succeeded == 2,
    call_api(batch, _{calls:[_{op:"reached", args:Reach}, _{op:"halt", args:_{}}]}, R2),
    R2.ok == false, R2.error.type == "invalid_call", R2.error.field == "calls[1]",
    call_api(batch, _{calls:[_{op:"batch", args:_{calls:[]}}]}, R3),
    R3.error.field == "calls[0]".
test(unknown_op_refused, [nondet]) :-
    call_api(halt, _{}, R), R.ok == false, R.error.type == "unknown_op".
test(injection_in_world_name, [nondet]) :-
    findall(W, world_exists(W), Before),
    call_api(create_world, _{world:"x), halt, (", landmarks:[]}, R),
    R.error.type == "invalid_id", R.error.field == "world",
    findall(W, world_exists(W), After),
    After == Before.
test(injection_in_landmark, [nondet, cleanup(drop_world(api1))]) :-
    mk(api1),
    call_api(observe, _{world:"api1", at:"a",
                        seen:[_{landmark:"b'), assertz(pwned), ('"}], angles:[], distances:[]}, R),
    R.error.type == "invalid_id", R.error.field == "seen[0].landmark",
    \+ catch(user:pwned, _, fail).
test(invalid_feature_names_field, [nondet, cleanup(drop_world(api7))]) :-
    mk(api7),
    call_api(observe, _{world:"api7", at:"a", seen:[_{landmark:"b", features:["Bad-id"]}],
                        angles:[], distances:[]}, R),
    R.error.type == "invalid_id", R.error.field == "seen[0].features".
test(unknown_landmark_names_field, [nondet, cleanup(drop_world(api2))]) :-
    mk(api2),
    call_api(observe, _{world:"api2", at:"a", seen:[_{landmark:"b"}, _{landmark:"zz"}],
                        angles:[], distances:[]}, R),
    R.error.type == "unknown_landmark", R.error.field == "seen[1].landmark".
test(failed_observation_leaves_facts, [nondet, cleanup(drop_world(api3))]) :-
    mk(api3),
    call_api(observe, _{world:"api3", at:"a", seen:[_{landmark:"b"}, _{landmark:"c"}],
                        angles:[["b", "c", 1.0]], distances:[]}, R1), R1.ok == true,
    call_api(observe, _{world:"api3", at:"a", seen:[_{landmark:"c"}],
                        angles:[["c", "b", "x"]], distances:[]}, R2), R2.ok == false,
    world_module(api3, M), M:lr(a, b, c), M:rec(a, b).
test(inference_limit, [nondet, cleanup(drop_world(api4))]) :-
    mk(api4),
    call_api(drm, _{world:"api4"}, 5, 10, R),
    R.ok == false, R.error.type == "limit".
test(unknown_world, [nondet]) :-
    call_api(drm, _{world:"nope"}, R), R.error.type == "unknown_world".
test(duplicate_landmarks_refused, [nondet]) :-
    call_api(create_world, _{world:"api5", landmarks:["a", "a"]}, R),
    R.error.type == "duplicate_landmark".
test(rule_probability_checked, [nondet]) :-
    call_api(create_world, _{world:"api6", landmarks:[], rule_probabilities:_{move2:1.5}}, R),
    R.error.type == "invalid_probability", R.error.field == "rule_probabilities.move2",
    call_api(create_world, _{world:"api6", landmarks:[], rule_probabilities:_{nosuch:0.5}}, R2),
    R2.error.type == "unknown_rule".

:- end_tests(api).
