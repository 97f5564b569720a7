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
      vp_unknown(Id, X, Y, AreaM2)       unknown region Id (integer >= 0),
                                         centroid (X, Y) m, area >= 0 m2
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

%   Unknown regions smaller than this (m2) are not observation groups.
params:default_parameter(vp_unknown_min_area_m2, 0.5).

%!  grouping_fact(?PI) is nondet.
%
%   The world facts this module reads and writes (declared per world in
%   world.pl).
grouping_fact(vp_candidate/5).
grouping_fact(vp_unknown/4).
grouping_fact(vp_group/3).
grouping_fact(vp_min_area/1).
grouping_fact(vp_plan_step/9).

%!  replace_viewpoint_scene(+World, +Candidates, +Regions, +MinAreaM2) is det.
%
%   Replaces every vp_* fact of World, in a transaction, by the candidates
%   (a list of vp_candidate/5 terms), the regions (a list of vp_unknown/4
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
    world_module(World, M),
    checked_list(Candidates, candidate, "candidates", Cs),
    checked_list(Regions, region, "regions", Rs),
    (   real(MinArea0, MinArea), MinArea >= 0.0
    ->  true
    ;   throw(chizu_error(invalid_number(MinArea0), "min_area_m2"))
    ),
    maplist(arg(1), Cs, CIds), unique_ids(CIds, duplicate_candidate, candidates),
    maplist(arg(1), Rs, RIds), unique_ids(RIds, duplicate_region, regions),
    scene_groups(Cs, Rs, MinArea, Gs),
    forall(member(vp_plan_step(K, G, _, _, _, _, _, _, _), Steps),
           (   memberchk(vp_group(G, _, _), Gs)
           ->  true
           ;   format(string(F), "steps[~d].group_id", [K]),
               throw(chizu_error(unknown_group(G), F))
           )),
    transaction(( forall(grouping_fact(N/A), ( functor(H, N, A), retractall(M:H) )),
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
normal_fact(region, vp_unknown(Id, X0, Y0, A0), vp_unknown(Id, X, Y, A)) :-
    integer(Id), Id >= 0,
    real(X0, X), real(Y0, Y), real(A0, A), A >= 0.0.

real(V, F) :-
    number(V),
    catch(F is float(V), _, fail),
    float_class(F, C), memberchk(C, [zero, subnormal, normal]).

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
    findall(R, ( member(vp_unknown(R, _, _, A), Rs), A >= MinArea ), Big0),
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
    M:vp_unknown(R, _, _, Area).
