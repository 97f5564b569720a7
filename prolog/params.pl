/*  Named parameters and rule probabilities.

    Every rule module contributes its defaults as multifile facts
    default_rule_probability(Rule, P) and default_parameter(Name, Value),
    written next to the rules they belong to.  A world may override any of
    them with its own rule_probability/2 or parameter/2 facts.
*/
:- module(params,
          [ rule_probability/3,     % +Module, +Rule, -P
            parameter/3,            % +Module, +Name, -Value
            rule_name/1,            % ?Rule
            parameter_name/1        % ?Name
          ]).

:- multifile default_rule_probability/2, default_parameter/2.
:- dynamic default_rule_probability/2, default_parameter/2.

%   Unknown regions smaller than this (m²) are not regions: neither a committed
%   SLAM map's (slam.pl, unknown_region/5) nor a viewpoint scene's (grouping.pl,
%   a group of its own to explore).  The one threshold both read.
default_parameter(unknown_region_min_area_m2, 0.5).

%!  rule_probability(+Module, +Rule, -P) is det.
%
%   P(head | body) of Rule in the world Module: the world's override if it
%   has one, else the default.  Unknown rules raise chizu_error(unknown_rule).
rule_probability(M, Rule, P) :-
    (   M:rule_probability(Rule, P0)
    ->  P = P0
    ;   default_rule_probability(Rule, P0)
    ->  P = P0
    ;   throw(chizu_error(unknown_rule(Rule)))
    ).

%!  parameter(+Module, +Name, -Value) is det.
parameter(M, Name, V) :-
    (   M:parameter(Name, V0)
    ->  V = V0
    ;   default_parameter(Name, V0)
    ->  V = V0
    ;   throw(chizu_error(unknown_parameter(Name)))
    ).

%!  rule_name(?Rule) is nondet.
rule_name(R) :- default_rule_probability(R, _).

%!  parameter_name(?Name) is nondet.
parameter_name(N) :- default_parameter(N, _).
