%% @doc EUnit tests of bil:explain_unbound/2: why an entry bound nothing.
-module(bil_explain_tests).

-include_lib("eunit/include/eunit.hrl").

entry(Cat, Type, Ps) -> #{category => Cat, type => Type, parameters => Ps}.

desc(Id, Type, Components) ->
    #{entity_id => Id, api_name => <<"t">>, entity_type => Type, context => <<>>,
      components => [#{id => C, services => S, consumes => U} || {C, S, U} <- Components]}.

%% A camera wanted in the kitchen; the avatar has one in the hall and one
%% that says nothing of rooms.
mismatch_names_the_parameter_test() ->
    Va = desc(<<"va">>, agent, [{<<"Eye">>, [], [entry(<<"SENSOR">>, <<"TakePhoto">>,
                                                       [{<<"Room">>, <<"Kitchen">>}])]}]),
    Av = desc(<<"av">>, avatar, [{<<"Cam1">>, [entry(<<"SENSOR">>, <<"take photo">>,
                                                   [{<<"room">>, <<"hall">>}])], []},
                                 {<<"Cam2">>, [entry(<<"SENSOR">>, <<"TakePhoto">>, [])], []},
                                 {<<"Mic">>, [entry(<<"SENSOR">>, <<"Listen">>, [])], []}]),
    #{unbound := [#{reason := parameters_mismatch} = U]} = bil:bind([Va, Av]),
    ?assertEqual([#{provider => #{entity => <<"av">>, component => <<"Cam1">>},
                    failed => [{<<"Room">>, <<"Kitchen">>, [<<"hall">>]}]},
                  #{provider => #{entity => <<"av">>, component => <<"Cam2">>},
                    failed => [{<<"Room">>, <<"Kitchen">>, []}]}],
                 bil:explain_unbound(U, [Va, Av])).

no_provider_has_no_candidates_test() ->
    Va = desc(<<"va">>, agent, [{<<"Ear">>, [], [entry(<<"SENSOR">>, <<"Smell">>, [])]}]),
    #{unbound := [#{reason := no_provider} = U]} = bil:bind([Va]),
    ?assertEqual([], bil:explain_unbound(U, [Va])).
