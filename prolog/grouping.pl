/*  Observation groups for viewpoint planning (Masuzawa & Miura, §4.2).

    A robot looking for objects has candidate objects (position, type and
    R_max, the largest distance at which that object can be recognised) and
    unknown regions of its occupancy grid (connected components computed
    numerically on the Python side: id, centroid, area).  Viewpoints are
    planned per observation group:

      - two candidates join when their distance is < R_max,1 + R_max,2, and
        the object groups are the connected components of that relation
        (so joining is transitive; a candidate that joins nobody is a group
        of its own);
      - every unknown region whose area is >= the threshold (m2) is a group
        of its own; smaller regions are in no group.

    These facts are kept per world (asserted only through the api op
    viewpoint_groups, which replaces all of them at once, so a new scene
    drops the previous one):

      vp_candidate(Id, Type, X, Y, RMax) candidate Id (an atom, valid_id/1),
                                         object type Type (a string, 1..64
                                         characters, never made an atom),
                                         position (X, Y) m, RMax > 0 m (X, Y
                                         and RMax at most 1e15 in magnitude,
                                         so distances cannot overflow)
      unknown_region(scene, Id, X, Y, AreaM2)
                                         unknown region Id (integer >= 0) of
                                         the plan's grid, centroid (X, Y) m,
                                         area >= 0 m2 (world.pl: the one
                                         unknown-region fact, a SLAM map's
                                         regions keyed by its run)
      vp_group(G, Kind, Members)         derived group G (integer >= 0);
                                         Kind = objects: Members is the sorted
                                         list of its candidates; Kind =
                                         unknown: Members = [RegionId]
      vp_min_area(A)                     the area threshold the scene used
      vp_plan_step(K, G, X, Y, Th, TravelM, ObserveS, PRecog, DoneAtS)
                                         step K (from 0) of the last plan: go to
                                         pose (X, Y, Th) for group G (travel
                                         TravelM m), observe ObserveS s;
                                         PRecog the chance the first look
                                         recognises its object (none for an
                                         unknown region); done at DoneAtS s

    Groups are numbered deterministically: object groups first, in the
    standard order of their (sorted) member lists, from 0; then the unknown
    groups by region id, numbered on from there.
*/
:- module(grouping,
          [ replace_viewpoint_scene/4, % +World, +Candidates, +Regions, +MinAreaM2
            replace_viewpoint_scene/5, % +World, +Candidates, +Regions, +MinAreaM2, +Steps
            plan_step/5,             % +World, ?K, ?G, ?Pose, ?Times
            grouping_fact/1,         % ?Name/Arity
            joinable/3,              % +World, ?A, ?B
            same_group/3,            % +World, ?A, ?B
            observation_group/4,     % +World, ?G, ?Kind, ?Members
            candidate_group/3,       % +World, ?Candidate, ?G
            unknown_group_area/3     % +World, ?G, ?Area
          ]).
:- use_module(library(apply)).
:- use_module(library(lists)).
:- use_module(library(pairs)).
:- use_module(library(assoc)).
:- use_module(world).
:- use_module(params).
:- use_module(json_args).
:- multifile api:run/3.

%   Unknown regions smaller than this (m2) are not observation groups.

%!  grouping_fact(?PI) is nondet.
%
%   The world facts this module reads and writes (declared per world in
%   world.pl).
grouping_fact(PI) :- domain_fact(viewpoint, PI).

:- multifile world:domain_fact/2.
world:domain_fact(viewpoint, vp_candidate/5).
world:domain_fact(viewpoint, vp_group/3).
world:domain_fact(viewpoint, vp_min_area/1).
world:domain_fact(viewpoint, vp_plan_step/9).

%!  replace_viewpoint_scene(+World, +Candidates, +Regions, +MinAreaM2) is det.
%
%   Replaces every vp_* fact of World, in a transaction, by the candidates
%   (a list of vp_candidate/5 terms), the regions (a list of unknown_region(scene, ...)
%   terms), the observation groups derived from them (vp_group/3) and
%   vp_min_area(MinAreaM2).  The api checks the input field by field; this
%   checks it again (a bad term throws chizu_error(invalid_fact(F)), a list
%   that is not one chizu_error(invalid_list, "candidates" | "regions"), a
%   bad threshold chizu_error(invalid_number(A), "min_area_m2")).  A repeated
%   candidate or region id throws chizu_error(duplicate_candidate(Id),
%   "candidates[I].id") or chizu_error(duplicate_region(Id),
%   "regions[I].id"), I being the position of the repeat.  On any error
%   nothing changes.  Numbers are stored as floats.
replace_viewpoint_scene(World, Candidates, Regions, MinArea) :-
    replace_viewpoint_scene(World, Candidates, Regions, MinArea, []).

%!  replace_viewpoint_scene(+World, +Candidates, +Regions, +MinAreaM2, +Steps) is det.
%
%   As replace_viewpoint_scene/4, and the plan's Steps (vp_plan_step/9
%   terms) with it; a step naming a group the scene does not have throws
%   chizu_error(unknown_group(G), "steps[K].group_id").
replace_viewpoint_scene(World, Candidates, Regions, MinArea0, Steps) :-
    checked_list(Candidates, candidate, "candidates", Cs),
    checked_list(Regions, region, "regions", Rs),
    (   real(MinArea0, MinArea), MinArea >= 0.0
    ->  true
    ;   throw(chizu_error(invalid_number(MinArea0), "min_area_m2"))
    ),
    store_viewpoint_scene(World, Cs, Rs, MinArea, Steps).

%   Candidates and regions already in normal form -- checked one by one, by
%   checked_list/4 or by the viewpoint_groups operation's field checks (each
%   is checked once) -- checked across (unique ids, steps naming groups), then
%   stored with their groups in one transaction.
store_viewpoint_scene(World, Cs, Rs, MinArea, Steps) :-
    world_module(World, M),
    maplist(arg(1), Cs, CIds), unique_ids(CIds, duplicate_candidate, candidates),
    maplist(arg(2), Rs, RIds), unique_ids(RIds, duplicate_region, regions),
    scene_groups(Cs, Rs, MinArea, Gs),
    forall(member(vp_plan_step(K, G, _, _, _, _, _, _, _), Steps),
           (   memberchk(vp_group(G, _, _), Gs)
           ->  true
           ;   format(string(F), "steps[~d].group_id", [K]),
               throw(chizu_error(unknown_group(G), F))
           )),
    transaction(( clear_domain(M, viewpoint),
                  forall(member(F, Cs), assertz(M:F)),
                  forall(member(F, Rs), assertz(M:F)),
                  forall(member(F, Gs), assertz(M:F)),
                  forall(member(F, Steps), assertz(M:F)),
                  assertz(M:vp_min_area(MinArea)) )).

%!  plan_step(+World, ?K, ?G, ?Pose, ?Times) is nondet.
%
%   Step K of World's last plan verifies group G from Pose = pose(X, Y, Th)
%   (m, rad); Times = times(TravelM, ObserveS, PRecog, DoneAtS).  Walk a plan
%   with ?- forall(plan_step(W, K, G, P, T), writeln(K-G-P-T)).
plan_step(World, K, G, pose(X, Y, Th), times(TravelM, ObserveS, PRecog, DoneAt)) :-
    world_module(World, M),
    M:vp_plan_step(K, G, X, Y, Th, TravelM, ObserveS, PRecog, DoneAt).

checked_list(L, Kind, Field, Normal) :-
    (   is_list(L) -> true ; throw(chizu_error(invalid_list, Field)) ),
    maplist(checked_fact(Kind), L, Normal).

checked_fact(Kind, F, N) :-
    (   nonvar(F), normal_fact(Kind, F, N0) -> N = N0 ; throw(chizu_error(invalid_fact(F))) ).

normal_fact(candidate, vp_candidate(Id, T, X0, Y0, R0), vp_candidate(Id, T, X, Y, R)) :-
    atom(Id), valid_id(Id),
    string(T), string_length(T, L), L >= 1, L =< 64,
    bounded(X0, X), bounded(Y0, Y), bounded(R0, R), R > 0.0.
normal_fact(region, unknown_region(scene, Id, X0, Y0, A0), unknown_region(scene, Id, X, Y, A)) :-
    integer(Id), Id >= 0,
    real(X0, X), real(Y0, Y), real(A0, A), A >= 0.0.

real(V, F) :- finite_real(V, F).

%   Candidate coordinates and R_max are at most 1e15 (m) in magnitude, so
%   that the distance arithmetic cannot overflow.
bounded(V, F) :- real(V, F), abs(F) =< 1.0e15.

%   Ids is duplicate-free; else throw Kind(Id) naming the first repeat.
unique_ids(Ids, Kind, List) :-
    empty_assoc(S0),
    foldl(unique_id(Kind, List), Ids, S0-0, _).

unique_id(Kind, List, Id, S0-I, S-I1) :-
    (   get_assoc(Id, S0, _)
    ->  E =.. [Kind, Id],
        format(string(Field), "~w[~d].id", [List, I]),
        throw(chizu_error(E, Field))
    ;   put_assoc(Id, S0, true, S),
        I1 is I + 1
    ).

		 /*******************************
		 *        DERIVED GROUPS        *
		 *******************************/

%   The vp_group/3 facts of a (checked) scene, numbered as described above.
scene_groups(Cs, Rs, MinArea, Groups) :-
    object_components(Cs, Comps),
    findall(R, ( member(unknown_region(scene, R, _, _, A), Rs), A >= MinArea ), Big0),
    sort(Big0, Big),
    foldl(object_group, Comps, OGs, 0, N),
    foldl(unknown_group, Big, UGs, N, _),
    append(OGs, UGs, Groups).

object_group(Ms, vp_group(G, objects, Ms), G, G1) :- G1 is G + 1.
unknown_group(R, vp_group(G, unknown, [R]), G, G1) :- G1 is G + 1.

%   The connected components of joins/6 over the candidates, each sorted,
%   in standard order.  Breadth-first search over the unvisited candidates,
%   kept sorted along the axis (x or y) on which they spread more, called u
%   below (v is the other one): a candidate A can only join candidates less
%   than RA + RM away in u (RM the largest R_max), so each search step stops
%   at the first unvisited candidate beyond that.  Worst case O(n^2) checks;
%   a dense scene empties the unvisited list quickly, a sparse one only
%   looks at near neighbours.  No edge list is built.
object_components([], []) :- !.
object_components(Cs, Comps) :-
    foldl(extent, Cs, e(inf, -inf, inf, -inf, 0.0), e(X0, X1, Y0, Y1, RM)),
    (   Y1 - Y0 > X1 - X0 -> Axis = y ; Axis = x ),
    maplist(sweep_point(Axis), Cs, Keyed),
    keysort(Keyed, ByU0),
    pairs_values(ByU0, ByU),
    components(ByU, RM, Comps0),
    sort(Comps0, Comps).

extent(vp_candidate(_, _, X, Y, R), e(X0, X1, Y0, Y1, R0), e(X2, X3, Y2, Y3, R1)) :-
    X2 is min(X0, X), X3 is max(X1, X),
    Y2 is min(Y0, Y), Y3 is max(Y1, Y),
    R1 is max(R0, R).

%   c(Id, U, V, R); joins/6 is symmetric in swapping x and y.
sweep_point(x, vp_candidate(Id, _, X, Y, R), X-c(Id, X, Y, R)).
sweep_point(y, vp_candidate(Id, _, X, Y, R), Y-c(Id, Y, X, R)).

components([], _, []).
components([S|U0], RM, [Comp|Comps]) :-
    grow([S|T]-T, U0, RM, Ids, U),
    sort(Ids, Comp),
    components(U, RM, Comps).

%   grow(+Queue, +Unvisited0, +RM, -Ids, -Unvisited): Ids are the queued
%   candidates and every candidate of Unvisited0 connected to them; Queue is
%   a difference list.
grow(H-T, U, _, [], U) :- H == T, !.
grow([A|H]-T, U0, RM, [IA|Ids], U) :-
    arg(1, A, IA),
    split(U0, A, RM, T, T1, U1),
    grow(H-T1, U1, RM, Ids, U).

%   split(+Unvisited0, +A, +RM, -Joined, ?Tail, -Unvisited): Joined (ending
%   in Tail) are the candidates of Unvisited0 that join A, in order.
split([], _, _, J, J, []).
split([B|Bs], A, RM, J, JT, U) :-
    A = c(_, UA, VA, RA),
    B = c(_, UB, VB, RB),
    DU is UB - UA,
    (   sqrt(DU*DU) >= RA + RM
    ->  (   DU > 0
        ->  J = JT, U = [B|Bs]      % so is every later B: stop here
        ;   U = [B|U1],
            split(Bs, A, RM, J, JT, U1)
        )
    ;   joins(UA, VA, RA, UB, VB, RB)
    ->  J = [B|J1],
        split(Bs, A, RM, J1, JT, U)
    ;   U = [B|U1],
        split(Bs, A, RM, J, JT, U1)
    ).

%   sqrt(DU*DU) >= RA + RM above implies that joins/6 fails for this B and,
%   if DU > 0, for every later B (both roundings are monotone).
joins(XA, YA, RA, XB, YB, RB) :-
    DX is XB - XA,
    DY is YB - YA,
    sqrt(DX*DX + DY*DY) < RA + RB.

		 /*******************************
		 *            RULES             *
		 *******************************/

%!  joinable(+World, ?A, ?B) is nondet.
%
%   A and B are different candidates of World whose distance is less than
%   the sum of their R_max.
joinable(World, A, B) :-
    world_module(World, M),
    M:vp_candidate(A, _, XA, YA, RA),
    M:vp_candidate(B, _, XB, YB, RB),
    A \== B,
    joins(XA, YA, RA, XB, YB, RB).

%!  same_group(+World, ?A, ?B) is nondet.
%
%   Candidates A and B are in the same object group (reflexive, symmetric
%   and transitive: the closure of joinable/3).
same_group(World, A, B) :-
    candidate_group(World, A, G),
    candidate_group(World, B, G).

%!  observation_group(+World, ?G, ?Kind, ?Members) is nondet.
%
%   Group G of World's scene: Kind = objects with its sorted candidates, or
%   Kind = unknown with Members = [RegionId].
observation_group(World, G, Kind, Members) :-
    world_module(World, M),
    M:vp_group(G, Kind, Members).

%!  candidate_group(+World, ?Candidate, ?G) is nondet.
%
%   Candidate is in object group G (every candidate is in exactly one).
candidate_group(World, C, G) :-
    world_module(World, M),
    (   nonvar(C)
    ->  M:vp_group(G0, objects, Ms),
        memberchk(C, Ms), !,
        G = G0
    ;   M:vp_group(G, objects, Ms),
        member(C, Ms)
    ).

%!  unknown_group_area(+World, ?G, ?Area) is nondet.
%
%   G is the group of an unknown region with area Area (m2).
unknown_group_area(World, G, Area) :-
    world_module(World, M),
    M:vp_group(G, unknown, [R]),
    M:unknown_region(scene, R, _, _, Area).


		 /*******************************
		 *   OPERATIONS (api.pl)        *
		 *******************************/

%   {world, candidates: [{id, type, x, y, r_max}], regions: [{id, x, y, area_m2}],
%    min_area_m2?}: replaces the world's viewpoint scene and replies with its
%   observation groups.  Without min_area_m2 (or with null) the world's
%   parameter unknown_region_min_area_m2 is used.
api:run(viewpoint_groups, Args, Reply) :-
    existing_world(Args, W),
    arg_(candidates, Args, Cs0), json_list(Cs0, candidates),
    foldl(vp_candidate_item, Cs0, Cs, 0, _),
    arg_(regions, Args, Rs0), json_list(Rs0, regions),
    foldl(vp_region_item, Rs0, Rs, 0, _),
    (   get_dict(min_area_m2, Args, A0), A0 \== null
    ->  nonneg_float("min_area_m2", A0, MinArea)
    ;   world_module(W, M),
        parameter(M, unknown_region_min_area_m2, A1),
        MinArea is float(A1)
    ),
    (   get_dict(steps, Args, Ss0), Ss0 \== null
    ->  json_list(Ss0, steps), foldl(vp_step_item, Ss0, Ss, 0, _)
    ;   Ss = []
    ),
    store_viewpoint_scene(W, Cs, Rs, MinArea, Ss),
    viewpoint_scene_reply(W, Reply).

api:run(viewpoint_scene, Args, Reply) :-
    existing_world(Args, W),
    viewpoint_scene_reply(W, Reply).

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
vp_region_item(D, unknown_region(scene, Id, X, Y, A), I, I1) :-
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
    dict_value(D, Key, F, V).

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
    ;   parameter(M, unknown_region_min_area_m2, A0), MinArea is float(A0)
    ).

vp_group_json(_, G, objects, Ms, _{id:G, kind:"objects", members:Ss}) :-
    maplist(atom_string, Ms, Ss).
vp_group_json(W, G, unknown, Ms, _{id:G, kind:"unknown", members:Ms, area_m2:A}) :-
    unknown_group_area(W, G, A).

