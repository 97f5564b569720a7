/*  Checked loading of chizu's rule modules.

    load_checked/1 raises if any file produced an error or warning while
    loading: a syntax error must stop start-up, not be printed and skipped.
    The service (service/kb.py) and the REPL entry load.pl both use it.
*/
:- module(loader, [load_checked/1, chizu_modules/1, message_text/2]).

:- dynamic load_problem/1.
:- multifile user:message_hook/3.
:- dynamic collecting/0.

user:message_hook(Term, Kind, _) :-
    collecting,
    memberchk(Kind, [error, warning]),
    assertz(load_problem(Term)),
    fail.

%!  chizu_modules(-Files) is det.
chizu_modules([world, params, qualitative, drm, eigenspace, slam, grouping, mission, query,
               api, repl]).

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
                                load_files(F, [if(true), imports([])]) )),
                       retractall(collecting)),
    findall(P, load_problem(P), Ps),
    (   Ps == []
    ->  true
    ;   maplist(message_text, Ps, Ss),
        throw(chizu_load_error(Ss))
    ).

%!  message_text(+Term, -Text:string) is det.
%
%   Text is how print_message/2 would show Term, or Term quoted if it has no
%   message translation.
message_text(E, Text) :-
    catch(( '$messages':translate_message(E, Lines, []),
            with_output_to(string(Text), print_message_lines(current_output, '', Lines)) ),
          _, fail),
    !.
message_text(E, Text) :-
    format(string(Text), "~q", [E]).

