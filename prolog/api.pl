/*  The one entry point the Python bridge calls: handle(+RequestJSON, -ReplyJSON).

    The request is JSON text passed as a Prolog string, never parsed as
    Prolog: {"op": Op, "args": {...}, "time_limit_s": T, "inference_limit": N}.
    Op must be one of the operations below; every user-given name inside args
    is checked by valid_id/1 before it becomes an atom.  Each operation runs
    under call_with_time_limit/2 and call_with_inference_limit/3, and every
    mutation runs in a transaction, so a limit or an error leaves the
    knowledge base as it was.

    Reply: {"ok": true, "result": R} or
           {"ok": false, "error": {"type": T, "detail": D, "field": F?, "value": V?}}.
*/
:- module(api, [handle/2, operation/1]).
:- use_module(library(http/json)).
:- use_module(library(time)).
:- use_module(library(apply)).
:- use_module(library(pairs)).
:- use_module(world).
:- use_module(params).
:- use_module(qualitative).
:- use_module(drm).
:- use_module(eigenspace).
:- use_module(slam).
:- use_module(grouping).
:- use_module(query).
:- use_module(loader, [message_text/2]).

%!  handle(+Request:text, -Reply:string) is det.
handle(In, Out) :-
    catch(handle_(In, Reply), E, error_reply(E, Reply)),
    !,
    atom_json_dict(Out, Reply, [width(0)]).
handle(_, Out) :-
    atom_json_dict(Out, _{ok:false, error:_{type:"failed", detail:"operation failed"}},
                   [width(0)]).

handle_(In, _{ok:true, result:Result}) :-
    atom_json_dict(In, Req, [value_string_as(string)]),
    get_dict(op, Req, OpText),
    get_dict(args, Req, Args),
    get_dict(time_limit_s, Req, T),
    get_dict(inference_limit, Req, N),
    atom_string(Op, OpText),
    (   operation(Op) -> true ; throw(chizu_error(unknown_op(OpText))) ),
    call_with_time_limit(
        T, call_with_inference_limit(once(run(Op, Args, Result)), N, Det)),
    (   Det == inference_limit_exceeded
    ->  throw(chizu_error(limit(inferences)))
    ;   true
    ).

%!  operation(?Op) is nondet.
operation(Op) :- clause(run(Op, _, _), _), atom(Op).

error_reply(chizu_error(E), R) :- !, error_reply(chizu_error(E, null), R).
error_reply(chizu_error(E, Field), _{ok:false, error:Err}) :- !,
    E =.. [Type|Values],
    format(string(Detail), "~q", [E]),
    Err0 = _{type:Type, detail:Detail},
    (   Values = [V|_], atomic(V) -> put_dict(value, Err0, V, Err1) ; Err1 = Err0 ),
    (   Field == null -> Err = Err1 ; put_dict(field, Err1, Field, Err) ).
error_reply(time_limit_exceeded, _{ok:false, error:_{type:limit, detail:"time limit exceeded", value:time}}) :- !.
error_reply(E, _{ok:false, error:_{type:internal, detail:Detail}}) :-
    message_text(E, Detail).

		 /*******************************
		 *        ARGUMENT CHECKS       *
		 *******************************/

arg_(Key, Dict, V) :-
    (   get_dict(Key, Dict, V0) -> V = V0 ; throw(chizu_error(missing(Key), Key)) ).

id_field(Text, Field, Id) :-
    (   valid_id(Text) -> atom_string(Id, Text) ; throw(chizu_error(invalid_id(Text), Field)) ).

existing_world(Args, W) :-
    arg_(world, Args, Text),
    id_field(Text, world, W),
    (   world_exists(W) -> true ; throw(chizu_error(unknown_world(W), world)) ).

known_landmark(W, Text, Field, L) :-
    id_field(Text, Field, L),
    world_module(W, M),
    (   M:landmark(L) -> true ; throw(chizu_error(unknown_landmark(L), Field)) ).

field(Fmt, Args, Field) :- format(string(Field), Fmt, Args).

probability(P, Field) :-
    (   number(P), P >= 0, P =< 1 -> true ; throw(chizu_error(invalid_probability(P), Field)) ).

		 /*******************************
		 *          OPERATIONS          *
		 *******************************/

run(engine, _, _{thread:Id}) :-
    thread_self(T), ( integer(T) -> Id = T ; thread_property(T, id(Id)) ).

run(worlds, _, Ws) :-
    findall(W, world_exists(W), Ws0), sort(Ws0, Ws).

run(create_world, Args, _{world:W, landmarks:N}) :-
    arg_(world, Args, Text), id_field(Text, world, W),
    arg_(landmarks, Args, Ls0),
    foldl([LT, L, I0, I]>>( field("landmarks[~d]", [I0], F), id_field(LT, F, L), I is I0+1 ),
          Ls0, Ls, 0, _),
    sort(Ls, Set), length(Set, N),
    (   length(Ls, N) -> true ; throw(chizu_error(duplicate_landmark, landmarks)) ),
    dict_pairs_or_empty(Args, rule_probabilities, RPs),
    forall(member(R-P, RPs),
           ( field("rule_probabilities.~w", [R], F),
             ( rule_name(R) -> true ; throw(chizu_error(unknown_rule(R), F)) ),
             probability(P, F) )),
    dict_pairs_or_empty(Args, parameters, Ps),
    forall(member(K-V, Ps),
           ( field("parameters.~w", [K], F),
             ( parameter_name(K) -> true ; throw(chizu_error(unknown_parameter(K), F)) ),
             ( number(V), V >= 0 -> true ; throw(chizu_error(invalid_parameter(V), F)) ) )),
    world_module(W, M),
    transaction(( create_world(W),
                  forall(member(L, Set), assertz(M:landmark(L))),
                  forall(member(R-P, RPs), assertz(M:rule_probability(R, P))),
                  forall(member(K-V, Ps), assertz(M:parameter(K, V))) )).

run(drop_world, Args, _{world:W}) :-
    existing_world(Args, W),
    drop_world(W).

run(landmarks, Args, Ls) :-
    existing_world(Args, W), world_module(W, M),
    findall(L, M:landmark(L), Ls).

run(observe, Args, _{world:W, at:At, relations:N}) :-
    existing_world(Args, W),
    arg_(at, Args, AtText), known_landmark(W, AtText, at, At),
    arg_(seen, Args, Seen0),
    foldl(seen_item(W, At), Seen0, Seen, 0, _),
    arg_(angles, Args, Angles0),
    maplist(angle_item(W, At), Angles0, Angles),
    arg_(distances, Args, Dists0),
    maplist(distance_item(W, At), Dists0, Dists),
    append(Angles, Dists, Quantities),
    observe(W, At, Seen, Quantities),
    world_module(W, M),
    aggregate_all(count, ( M:lr(At, _, _) ; M:align(At, _, _, _) ), N).

run(reached, Args, _{world:W, from:A, to:B}) :-
    existing_world(Args, W),
    arg_(from, Args, AT), known_landmark(W, AT, from, A),
    arg_(to, Args, BT), known_landmark(W, BT, to, B),
    transaction(record_reached(W, A, B)).

run(relations, Args, Rs) :-
    existing_world(Args, W),
    arg_(kind, Args, KT), atom_string(K, KT),
    (   relation_kind(K) -> true ; throw(chizu_error(unknown_kind(KT), kind)) ),
    findall(R, relation(K, W, R), Rs).

run(drm, Args, _{nodes:Ns, edges:Es}) :-
    existing_world(Args, W), world_module(W, M),
    findall(L, M:landmark(L), Ns),
    drm_edges(W, Edges),
    maplist([edge(A, B, P, Me, V), _{from:A, to:B, p:P, method:Me, via:V}]>>true, Edges, Es).

run(query, Args, _{solutions:Sols, truncated:Trunc}) :-
    existing_world(Args, W),
    arg_(goal, Args, Text),
    arg_(max_solutions, Args, Max),
    (   integer(Max), Max >= 1 -> true ; throw(chizu_error(invalid_max(Max), max_solutions)) ),
    world_query(W, Text, Max, Sols, Trunc).

run(params, Args, _{rule_probabilities:RPs, parameters:Ps}) :-
    existing_world(Args, W), world_module(W, M),
    findall(R-P, ( rule_name(R), rule_probability(M, R, P) ), RP0),
    dict_pairs(RPs, _, RP0),
    findall(K-V, ( parameter_name(K), parameter(M, K, V) ), P0),
    dict_pairs(Ps, _, P0).

run(facts, Args, Facts) :-
    existing_world(Args, W), world_module(W, M),
    findall(S, ( member(N/A, [landmark/1, rec/2, frec/3, lr/3, align/4, rea/2,
                              rule_probability/2, parameter/2,
                              eig_point/3, eig_triplet/4, eig_candidate_set/2,
                              map_pose/5, map_info/5, unknown_region/5,
                              committed_map/1, loop_closure/4,
                              vp_candidate/5, vp_unknown/4, vp_group/3, vp_min_area/1,
                              vp_plan_step/9]),
                 functor(H, N, A), M:H,
                 format(string(S), "~k", [H]) ),
            Facts).

%   {world, domain: "slam" | "eigenspace" | "viewpoint"}: removes every fact
%   of that domain from the world, in a transaction.  The service's rollback
%   when a world's first artifact of a kind fails to be stored: nothing was
%   stored, so nothing may stay asserted.
run(clear_facts, Args, _{world:W, domain:D}) :-
    existing_world(Args, W),
    arg_(domain, Args, DT),
    (   string(DT), atom_string(D, DT), domain_fact(D, _)
    ->  true
    ;   throw(chizu_error(unknown_domain(DT), domain))
    ),
    world_module(W, M),
    transaction(forall(domain_fact(D, N/A), ( functor(H, N, A), retractall(M:H) ))).

run(eigenspace_facts, Args, _{world:W, points:NP, triplets:NT, candidate_sets:NS}) :-
    existing_world(Args, W),
    arg_(points, Args, Ps0), json_list(Ps0, points),
    foldl(eig_point_item, Ps0, Ps, 0, NP),
    arg_(triplets, Args, Ts0), json_list(Ts0, triplets),
    foldl(eig_triplet_item(NP), Ts0, Ts, 0, NT),
    arg_(candidate_sets, Args, Ss0), json_list(Ss0, candidate_sets),
    foldl(eig_set_item(NT), Ss0, Sss, 0, NS),
    append(Sss, MFs),
    foldl(eig_set_disjoint, MFs, [], _),
    pairs_keys(MFs, Ms),
    append([Ps, Ts, Ms], Facts),
    replace_eigenspace_facts(W, Facts).

run(eigenspace_transition, Args, _{outcome:ON, sets:Sets, state:SJ}) :-
    existing_world(Args, W),
    arg_(state, Args, SJ0), json_state(W, SJ0, Prev),
    arg_(triplets, Args, Ts),
    arg_(unique, Args, U),
    stop_outcome(W, Ts, U, Outcome),
    next_state(Prev, Outcome, Next),
    outcome_json(Outcome, ON, Sets),
    state_json(Next, SJ).

run(eigenspace_covering, Args, Cs) :-
    existing_world(Args, W),
    arg_(x, Args, X), finite_number(X, x),
    arg_(y, Args, Y), finite_number(Y, y),
    findall(_{triplet:T, distance_m:D},
            ( covers(W, T, X, Y), triplet_distance(W, T, X, Y, D) ),
            Cs).

%   {world, run, poses: [[X, Y, Th]], info: {...}, regions: [{x, y, area_m2}],
%    closures?: [[ScanA, ScanB, Score]]}: replaces the world's SLAM facts.
%   closures is optional (calls stored before loop closures existed have
%   none): missing means no closures.
run(slam_facts, Args, _{world:W, run:Run, poses:NP, regions:NR, closures:NC}) :-
    existing_world(Args, W),
    arg_(run, Args, RunText), run_field(RunText, run, Run),
    arg_(poses, Args, Ps0), json_list(Ps0, poses),
    foldl(slam_pose_item(Run), Ps0, Ps, 0, NP),
    arg_(info, Args, Info0), slam_info(Run, Info0, Info),
    arg_(regions, Args, Rs0), json_list(Rs0, regions),
    foldl(slam_region_item(Run), Rs0, Rs, 0, NR),
    (   get_dict(closures, Args, Cs0) -> true ; Cs0 = [] ),
    json_list(Cs0, closures),
    foldl(slam_closure_item(Run), Cs0, Cs, 0, NC),
    append([[committed_map(Run), Info], Ps, Rs, Cs], Facts),
    replace_slam_facts(W, Facts).

run(slam_summary, Args, _{run:Run, explored_fraction:F, path_length_m:L, resolution_m:Res,
                         free_m2:Free, occupied_m2:Occ, unknown_m2:Unk, regions:Regions,
                         loop_closures:NC}) :-
    existing_world(Args, W),
    committed_map_run(W, Run),
    world_module(W, M),
    M:map_info(Run, Res, Free, Occ, Unk),
    explored_fraction(W, F),
    map_path_length(W, L),
    loop_closure_count(W, NC),
    findall(Id-_{id:Id, x:X, y:Y, area_m2:A}, M:unknown_region(Run, Id, X, Y, A), Rs0),
    keysort(Rs0, Rs),
    pairs_values(Rs, Regions).

run(slam_regions_near, Args, Regions) :-
    existing_world(Args, W),
    arg_(x, Args, X), finite_number(X, x),
    arg_(y, Args, Y), finite_number(Y, y),
    arg_(radius, Args, R), finite_number(R, radius),
    (   R >= 0 -> true ; throw(chizu_error(invalid_radius(R), radius)) ),
    committed_map_run(W, Run),
    world_module(W, M),
    findall((D-Id)-_{id:Id, x:RX, y:RY, area_m2:A, distance:D},
            ( unknown_region_within(W, X, Y, R, Id, D),
              M:unknown_region(Run, Id, RX, RY, A) ),
            Rs0),
    keysort(Rs0, Rs),
    pairs_values(Rs, Regions).

%   {world, candidates: [{id, type, x, y, r_max}], regions: [{id, x, y, area_m2}],
%    min_area_m2?}: replaces the world's viewpoint scene and replies with its
%   observation groups.  Without min_area_m2 (or with null) the world's
%   parameter vp_unknown_min_area_m2 is used.
run(viewpoint_groups, Args, Reply) :-
    existing_world(Args, W),
    arg_(candidates, Args, Cs0), json_list(Cs0, candidates),
    foldl(vp_candidate_item, Cs0, Cs, 0, _),
    arg_(regions, Args, Rs0), json_list(Rs0, regions),
    foldl(vp_region_item, Rs0, Rs, 0, _),
    (   get_dict(min_area_m2, Args, A0), A0 \== null
    ->  nonneg_float("min_area_m2", A0, MinArea)
    ;   world_module(W, M),
        parameter(M, vp_unknown_min_area_m2, A1),
        MinArea is float(A1)
    ),
    (   get_dict(steps, Args, Ss0), Ss0 \== null
    ->  json_list(Ss0, steps), foldl(vp_step_item, Ss0, Ss, 0, _)
    ;   Ss = []
    ),
    replace_viewpoint_scene(W, Cs, Rs, MinArea, Ss),
    viewpoint_scene_reply(W, Reply).

run(viewpoint_scene, Args, Reply) :-
    existing_world(Args, W),
    viewpoint_scene_reply(W, Reply).

%   The facts of each domain an artifact writes (clear_facts).
domain_fact(slam, PI) :- slam:slam_fact(PI).
domain_fact(eigenspace, PI) :- eigenspace:eigenspace_fact(PI).
domain_fact(viewpoint, PI) :- grouping:grouping_fact(PI).

dict_pairs_or_empty(Args, Key, Pairs) :-
    (   get_dict(Key, Args, D), is_dict(D) -> dict_pairs(D, _, Pairs) ; Pairs = [] ).

seen_item(W, At, S, seen(L, Fs), I0, I) :-
    I is I0 + 1,
    field("seen[~d].landmark", [I0], F),
    arg_(landmark, S, LT), known_landmark(W, LT, F, L),
    (   L == At -> throw(chizu_error(self_observation(L), F)) ; true ),
    (   get_dict(features, S, Fs0) -> true ; Fs0 = [] ),
    field("seen[~d].features", [I0], FF),
    maplist(feature_id(FF), Fs0, Fs).

%   Not a yall lambda: a compiled lambda would not see the bound FF.
feature_id(Field, Text, Id) :- id_field(Text, Field, Id).

angle_item(W, At, [T1, T2, D], angle(L1, At, L2, D)) :-
    known_landmark(W, T1, angles, L1), known_landmark(W, T2, angles, L2),
    (   number(D) -> true ; throw(chizu_error(invalid_angle(D), angles)) ).
distance_item(W, At, [T, D], distance(At, L, D)) :-
    known_landmark(W, T, distances, L),
    (   number(D) -> true ; throw(chizu_error(invalid_distance(D), distances)) ).

json_list(L, Field) :-
    (   is_list(L) -> true ; throw(chizu_error(invalid_list, Field)) ).

finite_number(V, Field) :-
    (   number(V), catch(F is float(V), _, fail), float_class(F, C),
        memberchk(C, [zero, subnormal, normal])
    ->  true
    ;   throw(chizu_error(invalid_number(V), Field))
    ).

finite_float(Field, V, F) :-
    finite_number(V, Field),
    F is float(V).

%   An index into a list of N items (JSON integers only, not 1.0).
index_in(I, N, Unknown, Field) :-
    (   integer(I), I >= 0 -> true ; throw(chizu_error(invalid_index(I), Field)) ),
    (   I < N -> true ; E =.. [Unknown, I], throw(chizu_error(E, Field)) ).

eig_point_item(P, eig_point(I, X, Y), I, I1) :-
    I1 is I + 1,
    field("points[~d]", [I], F),
    (   P = [X0, Y0] -> true ; throw(chizu_error(invalid_point, F)) ),
    finite_number(X0, F), finite_number(Y0, F),
    X is float(X0), Y is float(Y0).

eig_triplet_item(NP, D, eig_triplet(T, Ps, Ds, A), T, T1) :-
    T1 is T + 1,
    field("triplets[~d]", [T], F),
    (   is_dict(D) -> true ; throw(chizu_error(invalid_triplet, F)) ),
    field("triplets[~d].points", [T], FP),
    field("triplets[~d].directions_rad", [T], FD),
    field("triplets[~d].area_m2", [T], FA),
    (   get_dict(points, D, Ps) -> true ; throw(chizu_error(missing(points), FP)) ),
    (   is_list(Ps), length(Ps, 3) -> true ; throw(chizu_error(invalid_length(3), FP)) ),
    forall(member(P, Ps), index_in(P, NP, unknown_point, FP)),
    (   sort(Ps, [_, _, _]) -> true ; throw(chizu_error(duplicate_point, FP)) ),
    (   get_dict(directions_rad, D, Ds0) -> true ; throw(chizu_error(missing(directions_rad), FD)) ),
    (   is_list(Ds0), length(Ds0, 3) -> true ; throw(chizu_error(invalid_length(3), FD)) ),
    maplist(finite_float(FD), Ds0, Ds),
    (   get_dict(area_m2, D, A0) -> true ; throw(chizu_error(missing(area_m2), FA)) ),
    finite_number(A0, FA),
    (   A0 >= 0 -> A is float(A0) ; throw(chizu_error(invalid_area(A0), FA)) ).

%   Set ids are list positions + 1.
eig_set_item(NT, S, Facts, I, I1) :-
    I1 is I + 1,
    field("candidate_sets[~d]", [I], F),
    (   is_list(S), S \== [] -> true ; throw(chizu_error(invalid_set, F)) ),
    foldl(eig_set_member(NT, I), S, Facts, 0, _).

eig_set_member(NT, I, T, eig_candidate_set(M, T)-F, J, J1) :-
    J1 is J + 1,
    M is I + 1,
    field("candidate_sets[~d][~d]", [I, J], F),
    index_in(T, NT, unknown_triplet, F).

%   Every triplet is in at most one candidate set.
eig_set_disjoint(eig_candidate_set(_, T)-F, Seen, [T|Seen]) :-
    (   memberchk(T, Seen) -> throw(chizu_error(duplicate_triplet(T), F)) ; true ).

%   A SLAM run id (^r[0-9a-f]{1,64}$); the atom is made only after the check.
run_field(Text, Field, Run) :-
    (   valid_run_id(Text) -> atom_string(Run, Text) ; throw(chizu_error(invalid_run_id(Text), Field)) ).

%   The world's committed SLAM run; a world without one has no map to read.
committed_map_run(W, Run) :-
    (   committed_run(W, Run) -> true ; throw(chizu_error(unknown_map(W), world)) ).

%   Pose indices are list positions.
slam_pose_item(Run, P, map_pose(Run, I, X, Y, Th), I, I1) :-
    I1 is I + 1,
    field("poses[~d]", [I], F),
    (   is_list(P), P = [X0, Y0, Th0] -> true ; throw(chizu_error(invalid_pose, F)) ),
    maplist(finite_float(F), [X0, Y0, Th0], [X, Y, Th]).

slam_info(Run, D, map_info(Run, Res, Free, Occ, Unk)) :-
    (   is_dict(D) -> true ; throw(chizu_error(invalid_info, info)) ),
    maplist(slam_info_value(D), [resolution_m, free_m2, occupied_m2, unknown_m2],
            [Res, Free, Occ, Unk]).

slam_info_value(D, Key, V) :-
    field("info.~w", [Key], F),
    (   get_dict(Key, D, V0) -> true ; throw(chizu_error(missing(Key), F)) ),
    nonneg_float(F, V0, V).

nonneg_float(Field, V0, V) :-
    finite_float(Field, V0, V),
    (   V >= 0 -> true ; throw(chizu_error(invalid_number(V0), Field)) ).

%   Region ids are list positions.
slam_region_item(Run, D, unknown_region(Run, I, X, Y, A), I, I1) :-
    I1 is I + 1,
    field("regions[~d]", [I], F),
    (   is_dict(D) -> true ; throw(chizu_error(invalid_region, F)) ),
    slam_region_value(D, I, x, FX, X0), finite_float(FX, X0, X),
    slam_region_value(D, I, y, FY, Y0), finite_float(FY, Y0, Y),
    slam_region_value(D, I, area_m2, FA, A0), nonneg_float(FA, A0, A).

slam_region_value(D, I, Key, F, V) :-
    field("regions[~d].~w", [I, Key], F),
    (   get_dict(Key, D, V0) -> V = V0 ; throw(chizu_error(missing(Key), F)) ).

%   One loop closure [ScanA, ScanB, Score]: scan indices (JSON integers >= 0,
%   not 1.0) with ScanA < ScanB, and a match score in [0, 1].
slam_closure_item(Run, C, loop_closure(Run, A, B, S), I, I1) :-
    I1 is I + 1,
    field("closures[~d]", [I], F),
    (   is_list(C), C = [A, B, S0] -> true ; throw(chizu_error(invalid_closure, F)) ),
    (   integer(A), A >= 0 -> true ; throw(chizu_error(invalid_index(A), F)) ),
    (   integer(B), B >= 0 -> true ; throw(chizu_error(invalid_index(B), F)) ),
    (   A < B -> true ; throw(chizu_error(unordered_closure(A, B), F)) ),
    finite_float(F, S0, S),
    (   S =< 1.0, S >= 0.0 -> true ; throw(chizu_error(invalid_score(S0), F)) ).

%   One candidate {id, type, x, y, r_max}; the id becomes an atom only after
%   valid_id/1, the type stays a string.
vp_candidate_item(D, vp_candidate(Id, Type, X, Y, R), I, I1) :-
    I1 is I + 1,
    field("candidates[~d]", [I], F),
    (   is_dict(D) -> true ; throw(chizu_error(invalid_candidate, F)) ),
    maplist(vp_value(D, "candidates", I), [id, type, x, y, r_max], [FI, FT, FX, FY, FR],
            [IdText, Type, X0, Y0, R0]),
    id_field(IdText, FI, Id),
    (   string(Type), string_length(Type, L), L >= 1, L =< 64
    ->  true
    ;   throw(chizu_error(invalid_type(Type), FT))
    ),
    vp_coordinate(FX, X0, X),
    vp_coordinate(FY, Y0, Y),
    vp_coordinate(FR, R0, R),
    (   R > 0 -> true ; throw(chizu_error(invalid_number(R0), FR)) ).

%   One unknown region {id, x, y, area_m2}.
vp_region_item(D, vp_unknown(Id, X, Y, A), I, I1) :-
    I1 is I + 1,
    field("regions[~d]", [I], F),
    (   is_dict(D) -> true ; throw(chizu_error(invalid_region, F)) ),
    maplist(vp_value(D, "regions", I), [id, x, y, area_m2], [FI, FX, FY, FA],
            [Id, X0, Y0, A0]),
    (   integer(Id), Id >= 0 -> true ; throw(chizu_error(invalid_region_id(Id), FI)) ),
    finite_float(FX, X0, X),
    finite_float(FY, Y0, Y),
    nonneg_float(FA, A0, A).

vp_step_item(D, vp_plan_step(I, G, X, Y, Th, T, O, P, Done), I, I1) :-
    I1 is I + 1,
    field("steps[~d]", [I], F),
    (   is_dict(D) -> true ; throw(chizu_error(invalid_step, F)) ),
    maplist(vp_value(D, "steps", I), [group_id, pose, travel_m, observe_s, p_recog, done_at_s],
            [FG, FP, FT, FO, FR, FD], [G, Pose, T0, O0, P0, D0]),
    (   integer(G), G >= 0 -> true ; throw(chizu_error(invalid_group_id(G), FG)) ),
    (   is_list(Pose), length(Pose, 3) -> true ; throw(chizu_error(invalid_pose, FP)) ),
    maplist(vp_coordinate(FP), Pose, [X, Y, Th]),
    nonneg_float(FT, T0, T), nonneg_float(FO, O0, O), nonneg_float(FD, D0, Done),
    (   P0 == null -> P = none ; probability(P0, FR), P is float(P0) ).

vp_value(D, List, I, Key, F, V) :-
    field("~w[~d].~w", [List, I, Key], F),
    (   get_dict(Key, D, V0) -> V = V0 ; throw(chizu_error(missing(Key), F)) ).

%   Candidate coordinates and R_max: finite and at most 1e15 in magnitude
%   (grouping.pl squares distances).
vp_coordinate(Field, V0, V) :-
    finite_float(Field, V0, V),
    (   abs(V) =< 1.0e15 -> true ; throw(chizu_error(invalid_number(V0), Field)) ).

%   {groups: [...] ordered by id, min_area_m2: A} from World's stored scene;
%   a world without one has no groups and the threshold it would use.
viewpoint_scene_reply(W, _{groups:Groups, min_area_m2:MinArea, steps:Steps}) :-
    world_module(W, M),
    findall(G-J, ( observation_group(W, G, Kind, Ms), vp_group_json(W, G, Kind, Ms, J) ), Gs0),
    keysort(Gs0, Gs),
    pairs_values(Gs, Groups),
    findall(K-_{group_id:G, pose:[X, Y, Th], travel_m:T, observe_s:O, p_recog:PJ,
                done_at_s:Done},
            ( plan_step(W, K, G, pose(X, Y, Th), times(T, O, P, Done)),
              ( P == none -> PJ = null ; PJ = P ) ), Ss0),
    keysort(Ss0, Ss1),
    pairs_values(Ss1, Steps),
    (   M:vp_min_area(A) -> MinArea = A
    ;   parameter(M, vp_unknown_min_area_m2, A0), MinArea is float(A0)
    ).

vp_group_json(_, G, objects, Ms, _{id:G, kind:"objects", members:Ss}) :-
    maplist(atom_string, Ms, Ss).
vp_group_json(W, G, unknown, Ms, _{id:G, kind:"unknown", members:Ms, area_m2:A}) :-
    unknown_group_area(W, G, A).

%   {"state": "x"} | {"state": "y", "set": M | "unlisted"} | {"state": "z"}
json_state(W, D, State) :-
    (   is_dict(D), get_dict(state, D, K), string(K) -> true
    ;   throw(chizu_error(invalid_state, state))
    ),
    (   K == "x" -> State = x, no_set(D)
    ;   K == "z" -> State = z, no_set(D)
    ;   K == "y"
    ->  (   get_dict(set, D, S) -> true ; throw(chizu_error(missing(set), 'state.set')) ),
        (   S == "unlisted"
        ->  State = y(unlisted)
        ;   integer(S), S >= 1
        ->  world_module(W, M),
            (   M:eig_candidate_set(S, _) -> State = y(S)
            ;   throw(chizu_error(unknown_set(S), 'state.set'))
            )
        ;   throw(chizu_error(invalid_set(S), 'state.set'))
        )
    ;   throw(chizu_error(invalid_state(K), 'state.state'))
    ).

no_set(D) :-
    (   get_dict(set, D, S), S \== null -> throw(chizu_error(unexpected(set), 'state.set')) ; true ).

state_json(x, _{state:"x"}).
state_json(z, _{state:"z"}).
state_json(y(unlisted), _{state:"y", set:"unlisted"}) :- !.
state_json(y(M), _{state:"y", set:M}).

outcome_json(none, "none", []).
outcome_json(unique, "unique", []).
outcome_json(unlisted, "unlisted", []).
outcome_json(in_set(M), "in_set", [M]).
outcome_json(across(Ms), "across", Ms).

relation_kind(rec).
relation_kind(frec).
relation_kind(lr).
relation_kind(align).
relation_kind(rea).
relation_kind(reachable).

relation(rec, W, _{from:A, to:B, p:P}) :- rec(W, A, B, P).
relation(frec, W, _{from:A, to:B, feature:F, p:1.0}) :- frec(W, A, B, F).
relation(lr, W, _{at:A, left:B, right:C, p:P}) :- lr(W, A, B, C, P).
relation(align, W, _{at:A, first:B, second:C, kind:K, p:P}) :- align(W, A, B, C, K, P).
relation(rea, W, _{from:A, to:B, p:1.0}) :- world_module(W, M), M:rea(A, B).
relation(reachable, W, _{from:A, to:B, p:P, method:Me, via:V}) :-
    reachable(W, A, B, P, Me, V).
