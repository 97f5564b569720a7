/*  Read-only sandboxed queries over one world.

    The client's text is parsed as a term (never consulted or called as is),
    and the goal is checked against a whitelist before it runs:

      - control: (A, B), (A ; B), (A -> B), \+ A, true, fail, false
      - the world's relations, with the world argument filled in:
        rec/3, frec/3, lr/4, align/5, rea/2, landmark/1, reachable/4,
        reachable/5 (with Via), drm_edge/4
      - the eigenspace facts and rules (eigenspace.pl), world filled in:
        eig_point/3, eig_triplet/4, eig_candidate_set/2, stop_outcome/3,
        next_state/3, state_after/2, covers/3, triplet_distance/4
      - the SLAM map facts and rules (slam.pl), world filled in:
        map_pose/5, map_info/5, unknown_region/5 (a SLAM run's regions, or
        the viewpoint scene's: Map = scene), committed_map/1,
        loop_closure/4, explored_fraction/1, unknown_region_within/5,
        largest_unknown_region/2, map_path_length/1, loop_closure_count/1,
        closes_loop/2
      - the viewpoint-planning scene and its observation groups
        (grouping.pl), world filled in: vp_candidate/5,
        observation_group/3, same_group/2, joinable/2, candidate_group/2,
        unknown_group_area/2, plan_step/4 (the last plan's steps)
      - the last mission's record (mission.pl), world filled in:
        mission_step/3, mission_pose/3, mission_path/2, mission_outcome/1
      - comparison: =, \=, ==, \==, and <, >, =<, >=, =:= on numbers or
        variables only (no arithmetic expressions, so no arithmetic bombs)
      - member/2, memberchk/2
      - findall/3 and aggregate_all/3 (count, count(T), bag(T), set(T), and
        sum, max, min of a number or variable, max(X, W), min(X, W)) over an
        allowed goal

    Anything else (call/N, assert, I/O, halt, ...) raises
    chizu_error(not_allowed(Name/Arity)).  The query runs inside api:handle,
    so the time and inference limits apply, and at most MaxSolutions answers
    are returned.
*/
:- module(query, [world_query/5]).
:- use_module(library(solution_sequences)).
:- use_module(world).
:- use_module(qualitative).
:- use_module(drm).
:- use_module(eigenspace).
:- use_module(slam).
:- use_module(grouping).
:- use_module(mission).
:- use_module(json_args).
:- multifile api:run/3.

%!  world_query(+World, +Text, +MaxSolutions, -Solutions, -Truncated) is det.
%
%   Solutions is a list of dicts Var -> value (atoms as strings, numbers as
%   numbers, lists as lists, other terms as quoted text, unbound as null).
world_query(World, Text, Max, Solutions, Truncated) :-
    (   string(Text) ; atom(Text) ), !,
    catch(term_string(Goal0, Text, [variable_names(VNs)]), E,
          ( syntax_message(E, Msg), throw(chizu_error(syntax_error(Msg), goal)) )),
    safe(World, Goal0, Goal),
    Limit is Max + 1,
    catch(findall(VNs, limit(Limit, Goal), All0), error(E, _), goal_error(E)),
    length(All0, N),
    (   N > Max -> Truncated = true, length(All, Max), append(All, _, All0)
    ;   Truncated = false, All = All0
    ),
    maplist(bindings_dict, All, Solutions).
world_query(_, _, _, _, _) :-
    throw(chizu_error(invalid_goal, goal)).

%   An error the client's goal raised (an unbound argument to a comparison, a
%   type error) is the client's: chizu_error(goal_error(E), goal), a 422.
%   Limits (time, inferences) and resource errors pass on as they are.
goal_error(E) :-
    (   E = resource_error(_) -> throw(error(E, _)) ; true ),
    format(string(Msg), "~q", [E]),
    throw(chizu_error(goal_error(Msg), goal)).

syntax_message(error(syntax_error(What), _), Msg) :- !, format(string(Msg), "~w", [What]).
syntax_message(E, Msg) :- format(string(Msg), "~q", [E]).

bindings_dict(VNs, Dict) :-
    maplist([Name=Value, Name-J]>>json_value(Value, J), VNs, Pairs),
    dict_pairs(Dict, _, Pairs).

json_value(V, null) :- var(V), !.
json_value(V, V) :- integer(V), !.
json_value(V, V) :- float(V), float_class(V, C), memberchk(C, [zero, subnormal, normal]), !.
json_value(V, S) :- float(V), !, format(string(S), "~w", [V]).  % inf, nan: not JSON numbers
json_value(V, S) :- atom(V), !, atom_string(V, S).
json_value(V, V) :- string(V), !.
json_value(V, L) :- is_list(V), !, maplist(json_value, V, L).
json_value(V, S) :- format(string(S), "~q", [V]).

%!  safe(+World, +Goal, -Runnable) is det.
%
%   Runnable is Goal with the world filled in; throws if anything in Goal is
%   not whitelisted.
safe(_, G, _) :- var(G), !, throw(chizu_error(not_allowed(variable_goal), goal)).
safe(W, (A, B), (SA, SB)) :- !, safe(W, A, SA), safe(W, B, SB).
safe(W, (A ; B), (SA ; SB)) :- !, safe(W, A, SA), safe(W, B, SB).
safe(W, (A -> B), (SA -> SB)) :- !, safe(W, A, SA), safe(W, B, SB).
safe(W, \+ A, \+ SA) :- !, safe(W, A, SA).
safe(_, true, true) :- !.
safe(_, fail, fail) :- !.
safe(_, false, false) :- !.
safe(W, G, R) :- relation_goal(W, G, R), !.
safe(_, G, G) :- comparison(G), !.
safe(W, findall(T, A, L), findall(T, SA, L)) :- !, safe(W, A, SA).
safe(W, aggregate_all(Spec, A, R), aggregate_all(Spec, SA, R)) :- !,
    aggregate_spec(Spec), safe(W, A, SA).
safe(_, G, G) :- G = member(_, _), !.
safe(_, G, G) :- G = memberchk(_, _), !.
safe(_, G, _) :-
    (   callable(G) -> functor(G, N, A), PI = N/A ; PI = G ),
    throw(chizu_error(not_allowed(PI), goal)).

relation_goal(W, rec(A, B, P), qualitative:rec(W, A, B, P)).
relation_goal(W, frec(A, B, F), qualitative:frec(W, A, B, F)).
relation_goal(W, lr(A, B, C, P), qualitative:lr(W, A, B, C, P)).
relation_goal(W, align(A, B, C, K, P), qualitative:align(W, A, B, C, K, P)).
relation_goal(W, rea(A, B), M:rea(A, B)) :- world_module(W, M).
relation_goal(W, landmark(L), M:landmark(L)) :- world_module(W, M).
relation_goal(W, reachable(A, B, P, Me), drm:reachable(W, A, B, P, Me)).
relation_goal(W, reachable(A, B, P, Me, V), drm:reachable(W, A, B, P, Me, V)).
relation_goal(W, drm_edge(A, B, P, Me), drm:drm_edge(W, A, B, P, Me, _)).
relation_goal(W, eig_point(I, X, Y), M:eig_point(I, X, Y)) :- world_module(W, M).
relation_goal(W, eig_triplet(T, Ps, Ds, A), M:eig_triplet(T, Ps, Ds, A)) :- world_module(W, M).
relation_goal(W, eig_candidate_set(S, T), M:eig_candidate_set(S, T)) :- world_module(W, M).
relation_goal(W, stop_outcome(Ts, U, O), eigenspace:stop_outcome(W, Ts, U, O)).
relation_goal(_, next_state(S0, O, S), eigenspace:next_state(S0, O, S)).
relation_goal(W, state_after(Stops, S), eigenspace:state_after(W, Stops, S)).
relation_goal(W, covers(T, X, Y), eigenspace:covers(W, T, X, Y)).
relation_goal(W, triplet_distance(T, X, Y, D), eigenspace:triplet_distance(W, T, X, Y, D)).
relation_goal(W, map_pose(Run, I, X, Y, Th), M:map_pose(Run, I, X, Y, Th)) :- world_module(W, M).
relation_goal(W, map_info(Run, Res, F, O, U), M:map_info(Run, Res, F, O, U)) :- world_module(W, M).
relation_goal(W, unknown_region(Run, Id, X, Y, A), M:unknown_region(Run, Id, X, Y, A)) :-
    world_module(W, M).
relation_goal(W, committed_map(Run), M:committed_map(Run)) :- world_module(W, M).
relation_goal(W, loop_closure(Run, A, B, S), M:loop_closure(Run, A, B, S)) :-
    world_module(W, M).
relation_goal(W, explored_fraction(F), slam:explored_fraction(W, F)).
relation_goal(W, unknown_region_within(X, Y, R, Id, D), slam:unknown_region_within(W, X, Y, R, Id, D)).
relation_goal(W, largest_unknown_region(Id, A), slam:largest_unknown_region(W, Id, A)).
relation_goal(W, map_path_length(L), slam:map_path_length(W, L)).
relation_goal(W, loop_closure_count(N), slam:loop_closure_count(W, N)).
relation_goal(W, closes_loop(A, B), slam:closes_loop(W, A, B)).
relation_goal(W, vp_candidate(Id, T, X, Y, R), M:vp_candidate(Id, T, X, Y, R)) :-
    world_module(W, M).
relation_goal(W, observation_group(G, K, Ms), grouping:observation_group(W, G, K, Ms)).
relation_goal(W, same_group(A, B), grouping:same_group(W, A, B)).
relation_goal(W, joinable(A, B), grouping:joinable(W, A, B)).
relation_goal(W, candidate_group(C, G), grouping:candidate_group(W, C, G)).
relation_goal(W, unknown_group_area(G, A), grouping:unknown_group_area(W, G, A)).
relation_goal(W, plan_step(K, G, P, T), grouping:plan_step(W, K, G, P, T)).
relation_goal(W, mission_step(S, What, R), M:mission_step(S, What, R)) :- world_module(W, M).
relation_goal(W, mission_pose(X, Y, Th), mission:mission_pose(W, X, Y, Th)).
relation_goal(W, mission_path(Ls, P), mission:mission_path(W, Ls, P)).
relation_goal(W, mission_outcome(O), mission:mission_outcome(W, O)).

%   What aggregate_all/3 may gather: an expression would be arithmetic the
%   whitelist keeps out of comparisons too, so sum, max and min take a number
%   or a variable.
aggregate_spec(Spec) :- var(Spec), !, throw(chizu_error(not_allowed(variable_goal), goal)).
aggregate_spec(count) :- !.
aggregate_spec(count(_)) :- !.
aggregate_spec(bag(_)) :- !.
aggregate_spec(set(_)) :- !.
aggregate_spec(Spec) :-
    Spec =.. [Op, X], memberchk(Op, [sum, max, min]), !, num_or_var(X).
aggregate_spec(Spec) :-
    Spec =.. [Op, X, _], memberchk(Op, [max, min]), !, num_or_var(X).
aggregate_spec(Spec) :-
    (   callable(Spec) -> functor(Spec, N, A), PI = aggregate_all(N/A) ; PI = Spec ),
    throw(chizu_error(not_allowed(PI), goal)).

comparison(G) :-
    G =.. [Op, _, _],
    memberchk(Op, [=, \=, ==, \==, @<, @>]), !.
comparison(G) :-
    G =.. [Op, X, Y],
    memberchk(Op, [<, >, =<, >=, =:=, =\=]),
    num_or_var(X), num_or_var(Y).

num_or_var(X) :- ( var(X) ; number(X) ), !.
num_or_var(_) :- throw(chizu_error(not_allowed(arithmetic_expression), goal)).


		 /*******************************
		 *   OPERATIONS (api.pl)        *
		 *******************************/

api:run(query, Args, _{solutions:Sols, truncated:Trunc}) :-
    existing_world(Args, W),
    arg_(goal, Args, Text),
    arg_(max_solutions, Args, Max),
    (   integer(Max), Max >= 1 -> true ; throw(chizu_error(invalid_max(Max), max_solutions)) ),
    world_query(W, Text, Max, Sols, Trunc).

