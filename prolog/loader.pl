/*  Checked loading of chizu's rule modules.

    load_checked/1 raises if any file produced an error or warning while
    loading: a syntax error must stop start-up, not be printed and skipped.
    The service (service/kb.py) and the REPL entry load.pl both use it.
*/
:- module(loader, [load_checked/1, chizu_modules/1]).

:- dynamic load_problem/1.
:- multifile user:message_hook/3.
:- dynamic collecting/0.

user:message_hook(Term, Kind, _) :-
    collecting,
    memberchk(Kind, [error, warning]),
    assertz(load_problem(Term)),
    fail.

%!  chizu_modules(-Files) is det.
chizu_modules([world, params, qualitative, drm, query, api, repl]).

%!  load_checked(+Dir) is det.
%
%   Load every chizu module from Dir; throw chizu_load_error(Problems) if any
%   error or warning was printed while loading.
load_checked(Dir) :-
    retractall(load_problem(_)),
    chizu_modules(Ms),
    setup_call_cleanup(assertz(collecting),
                       forall(member(M, Ms),
                              ( directory_file_path(Dir, M, F),
                                load_files(F, [if(true)]) )),
                       retractall(collecting)),
    findall(P, load_problem(P), Ps),
    (   Ps == []
    ->  true
    ;   maplist([P, S]>>message_to_string(P, S), Ps, Ss),
        throw(chizu_load_error(Ss))
    ).

message_to_string(P, S) :-
    (   catch(message_to_codes(P, S), _, fail) -> true ; format(string(S), "~q", [P]) ).

message_to_codes(P, S) :-
    '$messages':translate_message(P, Lines, []),
    with_output_to(string(S), print_message_lines(current_output, '', Lines)).

