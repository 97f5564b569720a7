/*  The mission record, its rules and the mission_steps api op.

    Fixture: localize twice (the second reaches state z at (1.5, 2, 0.25)),
    the DRM path c_w -> c0 -> c1 (P 0.81), then an evaluation.
*/
:- begin_tests(mission).
:- use_module(library(http/json)).
:- use_module(world).
:- use_module(mission).
:- use_module(query).
:- use_module(api).

call_api(Op, Args, Reply) :-
    atom_json_dict(In, _{op:Op, args:Args, time_limit_s:5, inference_limit:10000000}, []),
    handle(In, Out),
    atom_json_dict(Out, Reply, []).

steps([ _{step:0, what:"localize", result:_{stops:1, state:"y", ok:true}},
        _{step:1, what:"localize", result:_{stops:2, state:"z", x:1.5, y:2, theta:0.25,
                                            ok:true}},
        _{step:2, what:"drm_path", result:_{from:"c_w", to:"c1",
                                            landmarks:["c_w", "c0", "c1"],
                                            methods:["move1", "move1"], probability:0.81,
                                            note:"Not an id", ok:true}},
        _{step:3, what:"evaluation", result:_{success:true, error_m:0.12}} ]).

fixture(W) :-
    call_api(create_world, _{world:W, landmarks:[]}, R0), R0.ok == true,
    steps(Ss),
    call_api(mission_steps, _{world:W, steps:Ss}, R), R.ok == true.

test(stored_as_terms, [nondet, cleanup(drop_world(m1))]) :-
    fixture(m1),
    world_module(m1, M),
    M:mission_step(2, drm_path, R),
    memberchk(landmarks = Ls, R), Ls == [c_w, c0, c1],
    memberchk(from = F, R), F == c_w,
    memberchk(probability = P, R), P == 0.81,
    memberchk(note = N, R), N == "Not an id",
    M:mission_step(1, localize, R1), memberchk(stops = St, R1), St == 2,
    memberchk(ok = true, R).
test(rules, [nondet, cleanup(drop_world(m2))]) :-
    fixture(m2),
    mission_pose(m2, X, Y, Th), X == 1.5, Y == 2.0, Th == 0.25,
    mission_path(m2, Ls, P), Ls == [c_w, c0, c1], P == 0.81,
    mission_outcome(m2, O), O == succeeded.
test(failed_step, [nondet, cleanup(drop_world(m3))]) :-
    call_api(create_world, _{world:m3, landmarks:[]}, _),
    call_api(mission_steps, _{world:m3, steps:[
        _{step:0, what:"localize", result:_{stops:10, state:"x", ok:false}}]}, R),
    R.ok == true,
    mission_outcome(m3, O), O == failed(localize),
    \+ mission_pose(m3, _, _, _).
test(replanned_path_is_the_last, [nondet, cleanup(drop_world(m6))]) :-
    %  an arc failed, the robot reached c0 and planned again: the path taken is
    %  the second, and the failed arc is no failed mission
    call_api(create_world, _{world:m6, landmarks:[]}, _),
    call_api(mission_steps, _{world:m6, steps:[
        _{step:0, what:"drm_path", result:_{landmarks:["c_w", "c2"], probability:0.9,
                                            replan:0, ok:true}},
        _{step:1, what:"arc_failed", result:_{from:"c_w", to:"c2", reason:"move1 failed"}},
        _{step:2, what:"reach_landmark", result:_{landmark:"c0", how:"replan", ok:true}},
        _{step:3, what:"drm_path", result:_{landmarks:["c0", "c1", "c2"],
                                            probability:0.8, replan:1, ok:true}},
        _{step:4, what:"evaluation", result:_{success:true}}]}, R),
    R.ok == true,
    mission_path(m6, Ls, P), Ls == [c0, c1, c2], P == 0.8,
    mission_outcome(m6, O), O == succeeded.
test(replaces, [nondet, cleanup(drop_world(m4))]) :-
    fixture(m4),
    call_api(mission_steps, _{world:m4, steps:[]}, R), R.ok == true,
    world_module(m4, M),
    \+ M:mission_step(_, _, _),
    \+ mission_outcome(m4, _).
test(bad_input_names_the_field, [nondet, cleanup(drop_world(m5))]) :-
    fixture(m5),
    forall(member(Steps-Field,
                  [ [_{step:0, what:"fly", result:_{}}]-"steps[0].what",
                    [_{step: -1, what:"localize", result:_{}}]-"steps[0].step",
                    [_{step:0, what:"localize", result:[]}]-"steps[0].result",
                    [_{step:0, what:"localize", result:_{x:_{a:1}}}]-"steps[0].result.x",
                    [_{step:0, what:"localize"}]-"steps[0].result",
                    [_{step:0, what:"localize", result:_{'X':1}}]-"steps[0].result.X",
                    ["x"]-"steps[0]" ]),
           ( call_api(mission_steps, _{world:m5, steps:Steps}, R),
             R.ok == false, R.error.field == Field )),
    % nothing changed
    mission_outcome(m5, O), O == succeeded.
test(query_sees_the_record, [nondet, cleanup(drop_world(m6))]) :-
    fixture(m6),
    world_query(m6, "mission_step(S, localize, R), member(state = z, R)", 5, Sols, false),
    Sols = [Sol], Sol.'S' == 1,
    world_query(m6, "mission_outcome(O)", 5, [O], false), O.'O' == "succeeded",
    world_query(m6, "mission_pose(X, Y, _)", 5, [P], false), P.'X' == 1.5.

:- end_tests(mission).
