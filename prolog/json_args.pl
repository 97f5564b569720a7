/*  The checks every operation's JSON arguments go through (api.pl and the
    domain modules that declare operations: qualitative, drm, eigenspace,
    slam, grouping, query).  Each throws chizu_error(Error, Field), Field
    naming the offending argument ("regions[3].area_m2"), and makes an atom
    of a client's text only after valid_id/1 has accepted it.
*/
:- module(json_args,
          [ arg_/3,                 % +Key, +Dict, -Value
            dict_value/4,           % +Dict, +Key, +Field, -Value
            id_field/3,             % +Text, +Field, -Id
            existing_world/2,       % +Args, -World
            known_landmark/4,       % +World, +Text, +Field, -Landmark
            field/3,                % +Format, +Args, -Field
            probability/2,          % +P, +Field
            json_list/2,            % +List, +Field
            finite_real/2,          % +V, -Float
            finite_number/2,        % +V, +Field
            finite_float/3,         % +Field, +V, -Float
            nonneg_float/3,         % +Field, +V, -Float
            index_in/4,             % +I, +N, +UnknownError, +Field
            dict_pairs_or_empty/3   % +Dict, +Key, -Pairs
          ]).
:- use_module(world).

%!  arg_(+Key, +Dict, -Value) is det.
%
%   The argument Key; chizu_error(missing(Key), Key) if it is absent.
arg_(Key, Dict, V) :- dict_value(Dict, Key, Key, V).

%!  dict_value(+Dict, +Key, +Field, -Value) is det.
%
%   As arg_/3 for an item of a list, whose field name Field says where it is.
dict_value(D, Key, Field, V) :-
    (   get_dict(Key, D, V0) -> V = V0 ; throw(chizu_error(missing(Key), Field)) ).

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

json_list(L, Field) :-
    (   is_list(L) -> true ; throw(chizu_error(invalid_list, Field)) ).

%!  finite_real(+V, -Float) is semidet.
%
%   V is a number whose float Float is finite: the one finiteness check of
%   chizu's Prolog side (JSON's numbers may be big integers or, from a
%   careless client, 1.0Inf or 1.5NaN).
finite_real(V, F) :-
    number(V),
    catch(F is float(V), _, fail),
    float_class(F, C), memberchk(C, [zero, subnormal, normal]).

%!  finite_number(+V, +Field) is det.
%
%   finite_real/2, or chizu_error(invalid_number(V), Field).
finite_number(V, Field) :-
    (   finite_real(V, _) -> true ; throw(chizu_error(invalid_number(V), Field)) ).

finite_float(Field, V, F) :-
    finite_number(V, Field),
    F is float(V).

nonneg_float(Field, V0, V) :-
    finite_float(Field, V0, V),
    (   V >= 0 -> true ; throw(chizu_error(invalid_number(V0), Field)) ).

%!  index_in(+I, +N, +Unknown, +Field) is det.
%
%   I indexes a list of N items (a JSON integer, not 1.0); else
%   chizu_error(invalid_index(I)) or chizu_error(Unknown(I)).
index_in(I, N, Unknown, Field) :-
    (   integer(I), I >= 0 -> true ; throw(chizu_error(invalid_index(I), Field)) ),
    (   I < N -> true ; E =.. [Unknown, I], throw(chizu_error(E, Field)) ).

dict_pairs_or_empty(Args, Key, Pairs) :-
    (   get_dict(Key, Args, D), is_dict(D) -> dict_pairs(D, _, Pairs) ; Pairs = [] ).
