/*  World modules: every world's knowledge lives in its own Prolog module.

    A world named `lab` is the module 'world:lab'.  Nothing outside this file
    builds that name, and every user-given name is validated by valid_id/1
    before it becomes an atom, so worlds never see each other's facts and a
    client string never becomes a goal.
*/
:- module(world,
          [ valid_id/1,             % +Text
            text_id/2,              % +Text, -Atom
            world_module/2,         % +World, -Module
            create_world/1,         % +World
            drop_world/1,           % +World
            world_exists/1,         % ?World
            clear_world/1,          % +World
            world_fact/1,           % ?Name/Arity
            domain_fact/2,          % ?Domain, ?Name/Arity
            clear_domain/2          % +Module, +Domain
          ]).

%!  domain_fact(?Domain, ?PI) is nondet.
%
%   The stored facts a world module holds, by the domain that writes them:
%   world (here), qualitative (qualitative.pl), eigenspace (eigenspace.pl),
%   slam (slam.pl), viewpoint (grouping.pl).  Each module declares its own
%   beside the rules that read them; the facts operation lists them, the
%   REPL loads them, clear_facts and the replace_* predicates clear them by
%   domain.
:- multifile domain_fact/2, derived_fact/1.
domain_fact(world, landmark/1).             % landmark(Id)
domain_fact(world, rule_probability/2).     % per-world override of a rule's P(head|body)
domain_fact(world, parameter/2).            % per-world override of a named parameter
%   unknown_region(Map, Id, X, Y, AreaM2): an enclosed unknown region (centroid
%   (X, Y) m, area m²) of a map: Map is a SLAM run (the committed map; slam.pl
%   writes those) or `scene` (the grid of the last viewpoint plan; grouping.pl
%   writes those).  The one unknown-region fact; region_owner/2 says whose.
domain_fact(map, unknown_region/5).

%!  region_owner(?Domain, +Map) is semidet.
%
%   Domain writes the unknown regions of Map.
region_owner(viewpoint, Map) :- Map == scene.
region_owner(slam, Map) :- Map \== scene.

%!  clear_domain(+Module, +Domain) is det.
%
%   Retracts Domain's facts from the world module Module: its own predicates
%   and the unknown regions of its maps.  Call it inside a transaction.
clear_domain(M, D) :-
    forall(domain_fact(D, N/A), ( functor(H, N, A), retractall(M:H) )),
    forall(( M:unknown_region(Map, _, _, _, _), region_owner(D, Map) ),
           retractall(M:unknown_region(Map, _, _, _, _))).

%!  derived_fact(?PI) is nondet.
%
%   Working state a world module holds besides its stored facts
%   (qualitative.pl: the materialised closure, the quantities of an
%   observation being converted).

%!  world_fact(?PI) is nondet.
%
%   Every dynamic predicate a world module holds.
world_fact(PI) :- domain_fact(_, PI).
world_fact(PI) :- derived_fact(PI).

%!  valid_id(+Text) is semidet.
%
%   True if Text (atom or string) is a valid world, landmark or feature id:
%   `^[a-z][a-zA-Z0-9_]{0,63}$`.
valid_id(Text) :-
    (   atom(Text) ; string(Text) ),
    atom_codes(Text, [C|Cs]),
    length(Cs, N), N =< 63,
    code_type(C, lower),
    C =< 0'z,
    forall(member(X, Cs), id_code(X)).

id_code(C) :- between(0'a, 0'z, C), !.
id_code(C) :- between(0'A, 0'Z, C), !.
id_code(C) :- between(0'0, 0'9, C), !.
id_code(0'_).

%!  text_id(+Text, -Id) is det.
%
%   Id is the atom for Text; throws chizu_error(invalid_id(Text)) otherwise.
text_id(Text, Id) :-
    (   valid_id(Text)
    ->  atom_string(Id, Text)
    ;   throw(chizu_error(invalid_id(Text)))
    ).

%!  world_module(+World, -Module) is det.
world_module(World, Module) :-
    text_id(World, Id),
    atom_concat('world:', Id, Module).

%!  create_world(+World) is det.
%
%   Creates (or empties) the module of World and declares its facts dynamic.
create_world(World) :-
    world_module(World, M),
    forall(world_fact(Name/Arity),
           ( functor(H, Name, Arity),
             dynamic(M:Name/Arity),
             retractall(M:H) )),
    text_id(World, Id),
    retractall(known_world(Id)),
    assertz(known_world(Id)).

:- dynamic known_world/1.

%!  world_exists(?World) is nondet.
world_exists(World) :-
    (   var(World)
    ->  known_world(World)
    ;   valid_id(World),
        atom_string(Id, World),
        known_world(Id)
    ).

%!  clear_world(+World) is det.
%
%   Removes every fact of World but keeps the world.
clear_world(World) :-
    world_module(World, M),
    forall(world_fact(Name/Arity),
           ( functor(H, Name, Arity), retractall(M:H) )).

%!  drop_world(+World) is det.
drop_world(World) :-
    clear_world(World),
    text_id(World, Id),
    retractall(known_world(Id)).

:- multifile prolog:message//1.
prolog:message(chizu_error(E)) --> [ 'chizu: ~q'-[E] ].
prolog:message(chizu_error(E, Field)) --> [ 'chizu: ~q (field ~w)'-[E, Field] ].
