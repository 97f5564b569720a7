/*  The end-to-end mission's record: what each step of a mission took and
    gave, as facts of the world it ran in, so that a REPL sees the mission
    beside the facts the steps produced (eigenspace analysis, DRM reached
    events, the committed SLAM map, the viewpoint scene).

    The service (service/mission.py) runs the steps -- wake up lost and
    localize by the eigenspace method with its movement strategy, name the
    nearest landmark, take the DRM's most probable path to the goal landmark
    and follow it by the qualitative navigation methods while mapping with
    laser SLAM, commit the map, plan viewpoints in the goal room and verify
    the candidate objects online -- and reports, after every step, the whole
    record so far (asserted only through the api op mission_steps, which
    replaces all of them at once):

      mission_step(S, What, Result)   step S (integer >= 0, in the order run)
                                      did What (an atom of mission_kind/1)
                                      and gave Result: a list of Key = Value
                                      (Key an atom, valid_id/1; Value an
                                      integer, a finite float, true/false, an id-like text as an
                                      atom, other text as a string, or a list
                                      of those)

    Inputs and outputs are both in Result (for localize: the stops taken and
    the pose; for drm_path: from, to, the landmarks and methods, P).  The
    step `evaluation` is the simulator's judgement against its ground truth
    (localization error, objects found); the robot never reads it.

    ?- mission_step(S, localize, R), member(x = X, R), member(y = Y, R).
    ?- mission_pose(X, Y, Th).           % (REPL shortcut, repl.pl)
*/
:- module(mission,
          [ replace_mission_steps/2, % +World, +Steps
            mission_kind/1,          % ?What
            mission_pose/4,          % +World, -X, -Y, -Th
            mission_path/3,          % +World, -Landmarks, -P
            mission_outcome/2        % +World, -Outcome
          ]).
:- use_module(library(apply)).
:- use_module(library(lists)).
:- use_module(world).
:- use_module(json_args).
:- multifile api:run/3.

:- multifile world:domain_fact/2.
world:domain_fact(mission, mission_step/3).

%!  mission_kind(?What) is nondet.
%
%   The steps a mission reports, in the order they run.
mission_kind(learn_eigenspace).
mission_kind(survey).
mission_kind(localize).
mission_kind(nearest_landmark).
mission_kind(reach_landmark).
mission_kind(landmark_fix).
mission_kind(drm_path).
mission_kind(arc_failed).
mission_kind(navigate).
mission_kind(slam_map).
mission_kind(enter_room).
mission_kind(viewpoint_plan).
mission_kind(verify).
mission_kind(evaluation).
mission_kind(aborted).

%!  replace_mission_steps(+World, +Steps) is det.
%
%   Replaces World's mission_step/3 facts by Steps (mission_step/3 terms, in
%   normal form), in a transaction.
replace_mission_steps(World, Steps) :-
    world_module(World, M),
    transaction(( clear_domain(M, mission),
                  forall(member(S, Steps), assertz(M:S)) )).

		 /*******************************
		 *            RULES             *
		 *******************************/

%!  mission_pose(+World, -X, -Y, -Th) is semidet.
%
%   The pose the mission's localization gave (the last localize step that
%   reached state z).
mission_pose(World, X, Y, Th) :-
    world_module(World, M),
    findall(R, ( M:mission_step(_, localize, R), memberchk(state = z, R) ), Rs),
    last(Rs, R),
    memberchk(x = X0, R), memberchk(y = Y0, R), memberchk(theta = Th0, R),
    X is float(X0), Y is float(Y0), Th is float(Th0).

%!  mission_path(+World, -Landmarks, -P) is semidet.
%
%   The DRM path the mission took last (after a failed arc it plans again)
%   and its probability.
mission_path(World, Ls, P) :-
    world_module(World, M),
    findall(R, M:mission_step(_, drm_path, R), Rs),
    last(Rs, R),
    memberchk(landmarks = Ls, R), memberchk(probability = P, R).

%!  mission_outcome(+World, -Outcome) is semidet.
%
%   succeeded if the last step is an evaluation saying so, failed(What) if a
%   step reported `ok = false` (What: the first such step), running
%   otherwise.
mission_outcome(World, Outcome) :-
    world_module(World, M),
    findall(S-W-R, M:mission_step(S, W, R), Steps),
    Steps \== [],
    (   member(_-W-R, Steps), W \== evaluation, memberchk(ok = false, R)
    ->  Outcome = failed(W)
    ;   last(Steps, _-evaluation-R), memberchk(success = true, R)
    ->  Outcome = succeeded
    ;   last(Steps, _-evaluation-_)
    ->  Outcome = failed(evaluation)
    ;   Outcome = running
    ).

		 /*******************************
		 *   OPERATIONS (api.pl)        *
		 *******************************/

%   mission_steps: {world, steps: [{step, what, result: {key: value}}]}
api:run(mission_steps, Args, _{world:W, steps:N}) :-
    existing_world(Args, W),
    arg_(steps, Args, Ss0), json_list(Ss0, steps),
    foldl(step_item, Ss0, Ss, 0, N),
    replace_mission_steps(W, Ss).

step_item(D, mission_step(S, What, Result), I, I1) :-
    I1 is I + 1,
    field("steps[~d]", [I], F),
    (   is_dict(D) -> true ; throw(chizu_error(invalid_step, F)) ),
    field("steps[~d].step", [I], FS),
    dict_value(D, step, FS, S),
    (   integer(S), S >= 0 -> true ; throw(chizu_error(invalid_index(S), FS)) ),
    field("steps[~d].what", [I], FW),
    dict_value(D, what, FW, WT),
    (   string(WT), atom_string(What, WT), mission_kind(What)
    ->  true
    ;   throw(chizu_error(unknown_step_kind(WT), FW))
    ),
    field("steps[~d].result", [I], FR),
    dict_value(D, result, FR, R0),
    (   is_dict(R0) -> true ; throw(chizu_error(invalid_result, FR)) ),
    dict_pairs(R0, _, Pairs),
    maplist(result_pair(FR), Pairs, Result).

result_pair(F, K0-V0, K = V) :-
    atom_string(K0, KT),
    field("~w.~w", [F, KT], FK),
    id_field(KT, FK, K),
    result_value(FK, V0, V).

result_value(_, V, V) :- memberchk(V, [true, false]), !.
result_value(_, V, V) :- integer(V), !.
result_value(_, V, F) :- finite_real(V, F), !.
result_value(_, V, A) :- string(V), valid_id(V), !, atom_string(A, V).
result_value(F, V, V) :-
    string(V), !,
    string_length(V, L),
    (   L =< 1000 -> true ; throw(chizu_error(too_long, F)) ).
result_value(F, V, L) :- is_list(V), !, maplist(result_value(F), V, L).
result_value(F, V, _) :- throw(chizu_error(invalid_value(V), F)).
