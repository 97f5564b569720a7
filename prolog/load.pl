/*  chizu knowledge base REPL entry: `swipl prolog/load.pl`.

    Loads every rule module (refusing to carry on after a load error) and
    puts the REPL shortcuts (repl.pl) into `user`.
*/
:- use_module(loader).
:- prolog_load_context(directory, D),
   catch(load_checked(D), chizu_load_error(Ps),
         ( forall(member(P, Ps), format(user_error, "~s~n", [P])), halt(1) )).
:- use_module(repl).
