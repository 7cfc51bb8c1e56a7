%% Bounded explanations of unbound entries (evatar_web_explain): the same
%% answer as bil:explain_unbound/2 over every description, capped.
-module(evatar_web_explain_tests).

-include_lib("eunit/include/eunit.hrl").

desc(E, Type, Components) ->
    #{entity_id => E, api_name => <<"api">>, entity_type => Type, context => <<"c">>,
      components => Components}.

comp(Id, Services, Consumes) ->
    #{id => Id, services => Services, consumes => Consumes}.

entry(Cat, Type, Ps) ->
    #{category => Cat, type => Type, parameters => Ps}.

unbound(E, C, Cat, Type) ->
    #{consumer => #{entity => E, component => C}, category => Cat, type => Type,
      reason => parameters_mismatch}.

%% Under the cap the answer is bil's, over every description, unchanged:
%% case-insensitive keys, providers of the consumer's own side left out,
%% an unknown consumer or key explained as no candidate.
same_as_bil_under_cap_test() ->
    Agent = desc(<<"va">>, agent, [comp(<<"Brain">>, [entry(<<"SENSOR">>, <<"Cam">>, [])],
                                        [entry(<<"ACTUATOR">>, <<"Light">>, [{<<"Colour">>, <<"red">>}]),
                                         entry(<<"ACTUATOR">>, <<"Door">>, [])])]),
    Other = desc(<<"va2">>, agent, [comp(<<"X">>, [entry(<<"actuator">>, <<"light">>, [])], [])]),
    Av1 = desc(<<"av1">>, avatar, [comp(<<"Lamp">>, [entry(<<"actuator">>, <<"LIGHT">>,
                                                         [{<<"colour">>, <<"blue">>}])], [])]),
    Av2 = desc(<<"av2">>, avatar, [comp(<<"L1">>, [entry(<<"ACTUATOR">>, <<"Light">>, [])], []),
                                   comp(<<"L2">>, [entry(<<"ACTUATOR">>, <<"Light">>,
                                                         [{<<"Colour">>, <<"green">>}])], [])]),
    Ds = [Agent, Other, Av1, Av2],
    Index = evatar_web_explain:index(Ds),
    [begin
         {Got, 0} = evatar_web_explain:explain(U, Index),
         ?assertEqual(bil:explain_unbound(U, Ds), Got)
     end || U <- [unbound(<<"va">>, <<"Brain">>, <<"ACTUATOR">>, <<"Light">>),
                  unbound(<<"va">>, <<"Brain">>, <<"ACTUATOR">>, <<"Door">>),
                  unbound(<<"nobody">>, <<"Brain">>, <<"ACTUATOR">>, <<"Light">>)]],
    {[_, _, _], 0} = evatar_web_explain:explain(unbound(<<"va">>, <<"Brain">>, <<"ACTUATOR">>,
                                                        <<"Light">>), Index).

%% Many unbound entries against many candidate providers: each gets at most
%% max_candidates/0 explained, the first ones in document order and as bil
%% explains them, and the count of the others.
many_unbound_entries_test() ->
    Cap = evatar_web_explain:max_candidates(),
    NProviders = Cap * 4,
    NUnbound = 500,
    Consumes = [entry(<<"ACTUATOR">>, <<"Move">>, [{<<"Speed">>, integer_to_binary(I)}])
                || I <- lists:seq(1, NUnbound)],
    Agent = desc(<<"va">>, agent, [comp(<<"Brain">>, [], Consumes)]),
    Avatars = [desc(integer_to_binary(I), avatar,
                    [comp(<<"Wheel">>, [entry(<<"ACTUATOR">>, <<"Move">>, [{<<"Speed">>, <<"0">>}])], [])])
               || I <- lists:seq(1, NProviders)],
    Ds = [Agent | Avatars],
    Index = evatar_web_explain:index(Ds),
    Answers = [evatar_web_explain:explain(unbound(<<"va">>, <<"Brain">>, <<"ACTUATOR">>, <<"Move">>), Index)
               || _ <- lists:seq(1, NUnbound)],
    NUnbound = length(Answers),
    {Shown, More} = hd(Answers),
    ?assertEqual(Cap, length(Shown)),
    ?assertEqual(NProviders - Cap, More),
    Full = bil:explain_unbound(unbound(<<"va">>, <<"Brain">>, <<"ACTUATOR">>, <<"Move">>), Ds),
    ?assertEqual(NProviders, length(Full)),
    ?assertEqual(lists:sublist(Full, Cap), Shown).
