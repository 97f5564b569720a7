/*  The one entry point the Python bridge calls: handle(+RequestJSON, -ReplyJSON).

    The request is JSON text passed as a Prolog string, never parsed as
    Prolog: {"op": Op, "args": {...}, "time_limit_s": T, "inference_limit": N}.
    Op must be one of the operations (run/3: the world's below, each domain's
    in its own module); every user-given name inside args is checked by
    valid_id/1 (json_args.pl) before it becomes an atom.  Each operation runs
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
:- use_module(json_args).
:- use_module(loader, [message_text/2]).

%!  run(+Op, +Args:dict, -Reply) is semidet.
%
%   The operations, one clause each.  This module holds the world's own (engine,
%   worlds, create_world, drop_world, landmarks, params, facts, clear_facts);
%   each domain module declares its own beside its rules, with the argument
%   checks of json_args.pl: observe and reached (qualitative.pl), relations and
%   drm (drm.pl), query (query.pl), eigenspace_* (eigenspace.pl), slam_*
%   (slam.pl), viewpoint_* (grouping.pl).
:- multifile run/3.

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
    Goal = call_with_inference_limit(once(run(Op, Args, Result)), N, Det),
    (   get_dict(cancellable, Req, true)
    ->  call_with_time_limit(T, with_cancel_checks(Goal))
    ;   call_with_time_limit(T, Goal)
    ),
    (   Det == inference_limit_exceeded
    ->  throw(chizu_error(limit(inferences)))
    ;   true
    ).

%!  with_cancel_checks(:Goal) is semidet.
%
%   Goal, asking the bridge every 0.1 s whether the job was cancelled (its client
%   left): chizu_cancelled/0 is a foreign predicate the Python bridge registers;
%   if it succeeds, the job stops with chizu_error(cancelled).  Without the
%   bridge (swipl on its own) the check never fires.
with_cancel_checks(Goal) :-
    setup_call_cleanup(arm_cancel_check, Goal, disarm_cancel_check).

%   The alarm is recorded before it is installed, and a fired one stays until it
%   is removed here (never remove(true): removing an alarm that removed itself
%   aborts SWI-Prolog 9.0), so a time limit striking anywhere in between leaves no
%   alarm behind to fire into a later job.
arm_cancel_check :-
    alarm(0.1, cancel_check, Id, [install(false)]),
    nb_setval(chizu_cancel_alarm, Id),
    install_alarm(Id).

disarm_cancel_check :-
    (   nb_current(chizu_cancel_alarm, Id), Id \== none
    ->  nb_setval(chizu_cancel_alarm, none), remove_alarm(Id)
    ;   true
    ).

cancel_check :-
    disarm_cancel_check,
    % the bridge defines it at run time (foreign): built here, so that the load
    % check does not report an undefined predicate when Prolog runs without it
    Check =.. [chizu_cancelled],
    (   catch(api:Check, error(existence_error(_, _), _), fail)
    ->  throw(chizu_error(cancelled))
    ;   arm_cancel_check
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
		 *          OPERATIONS          *
		 *******************************/

%   Several operations in one engine call, in order: a world's stored events
%   replayed (service/worlds.py) pay one round trip for many.  Each runs as it
%   would alone (its own transaction); the first error stops the batch.
run(batch, Args, Results) :-
    arg_(calls, Args, Calls),
    json_list(Calls, calls),
    foldl(batch_call, Calls, Results, 0, _).

batch_call(Call, Result, I, I1) :-
    I1 is I + 1,
    field("calls[~d]", [I], F),
    (   is_dict(Call), get_dict(op, Call, OpText), get_dict(args, Call, Args),
        ( string(OpText) ; atom(OpText) ), atom_string(Op, OpText),
        operation(Op), Op \== batch
    ->  once(run(Op, Args, Result))
    ;   throw(chizu_error(invalid_call, F))
    ).

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

run(params, Args, _{rule_probabilities:RPs, parameters:Ps}) :-
    existing_world(Args, W), world_module(W, M),
    findall(R-P, ( rule_name(R), rule_probability(M, R, P) ), RP0),
    dict_pairs(RPs, _, RP0),
    findall(K-V, ( parameter_name(K), parameter(M, K, V) ), P0),
    dict_pairs(Ps, _, P0).

%   Every stored fact of the world (domain_fact/2: what each domain declares),
%   as Prolog text.
run(facts, Args, Facts) :-
    existing_world(Args, W), world_module(W, M),
    fact_texts(M, _, Facts).

%   {world}: the qualitative facts the world's events made (domain
%   qualitative: rec, frec, lr, align, rea), as Prolog text -- a snapshot the
%   service stores so that a restart need not replay every event.
run(snapshot, Args, Facts) :-
    existing_world(Args, W), world_module(W, M),
    fact_texts(M, qualitative, Facts).

%   The facts of Domain (any, if unbound) in world module M, as Prolog text.
fact_texts(M, Domain, Facts) :-
    findall(S, ( domain_fact(Domain, N/A),
                 functor(H, N, A), M:H,
                 format(string(S), "~k", [H]) ),
            Facts).

%   {world, facts: [Text]}: asserts a snapshot's facts (as the snapshot op wrote
%   them) into the world, in a transaction.  Each text is read as data, with no
%   variables, and only qualitative fact shapes with ground arguments are
%   asserted; anything else throws chizu_error(not_a_fact(Text), "facts[I]").
run(load_snapshot, Args, _{world:W, facts:N}) :-
    existing_world(Args, W), world_module(W, M),
    arg_(facts, Args, Texts), json_list(Texts, facts),
    foldl(snapshot_fact, Texts, Facts, 0, N),
    transaction(forall(member(F, Facts), assertz(M:F))).

snapshot_fact(Text, F, I, I1) :-
    I1 is I + 1,
    field("facts[~d]", [I], Field),
    (   string(Text),
        catch(term_string(F, Text, [variable_names([])]), _, fail),
        ground(F), functor(F, N, A), domain_fact(qualitative, N/A)
    ->  true
    ;   throw(chizu_error(not_a_fact(Text), Field))
    ).

%   {world, domain: "slam" | "eigenspace" | "viewpoint"}: removes every fact
%   of that domain from the world, in a transaction.  The service's rollback
%   when a world's first artifact of a kind fails to be stored: nothing was
%   stored, so nothing may stay asserted.
run(clear_facts, Args, _{world:W, domain:D}) :-
    existing_world(Args, W),
    arg_(domain, Args, DT),
    (   string(DT), atom_string(D, DT), memberchk(D, [slam, eigenspace, viewpoint, mission])
    ->  true
    ;   throw(chizu_error(unknown_domain(DT), domain))
    ),
    world_module(W, M),
    transaction(clear_domain(M, D)).
