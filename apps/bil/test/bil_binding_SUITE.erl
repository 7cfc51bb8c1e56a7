%% @doc Checks bil:bind/1 against docs/bil.md section 4 (Binding): one
%% concrete case per rule, and PropEr properties that compare it with a
%% naive reference written straight from the rules text.
-module(bil_binding_SUITE).

%% The PropEr runner the suites share (apps/evatar_test_kit).
-import(evatar_test_proper, [check/2]).

-include_lib("common_test/include/ct.hrl").
-include_lib("proper/include/proper.hrl").

-export([all/0, groups/0, suite/0]).
-export([keyword_equivalence/1, keyword_unicode/1, keyword_invalid_utf8/1,
         keyword_binding/1, same_type_never_binds/1, own_service_never_binds/1,
         param_no/1, param_yes/1, param_value/1, param_any_consumer_value/1,
         score_ordering/1, score_counts_names_once/1, tie_registration_order/1,
         tie_document_order/1, candidates_count/1, unbound_no_provider/1,
         unbound_parameters_mismatch/1, several_consumers_one_provider/1,
         result_order/1, keeps_consumer_spelling/1, empty_input/1,
         prop_matches_reference/1, prop_each_consumer_once/1,
         prop_provider_other_type/1, prop_matches_old/1, prop_matches_old_shared/1,
         prop_matches_old_any/1,
         old_matches_at_scale/1]).

-define(NUMTESTS_REFERENCE, 600).
-define(NUMTESTS, 300).

%% ---------------------------------------------------------------------------
%% Common Test
%% ---------------------------------------------------------------------------

suite() ->
    [{timetrap, {minutes, 3}}].

all() ->
    [{group, keywords}, {group, rules}, {group, properties}].

groups() ->
    [{keywords, [parallel],
      [keyword_equivalence, keyword_unicode, keyword_invalid_utf8]},
     {rules, [parallel],
      [keyword_binding, same_type_never_binds, own_service_never_binds,
       param_no, param_yes, param_value, param_any_consumer_value,
       score_ordering, score_counts_names_once, tie_registration_order,
       tie_document_order, candidates_count, unbound_no_provider,
       unbound_parameters_mismatch, several_consumers_one_provider,
       result_order, keeps_consumer_spelling, empty_input]},
     {properties, [],
      [prop_matches_reference, prop_each_consumer_once, prop_provider_other_type,
       prop_matches_old, prop_matches_old_shared, prop_matches_old_any,
       old_matches_at_scale]}].

%% ---------------------------------------------------------------------------
%% Keywords (rule 1)
%% ---------------------------------------------------------------------------

%% @doc Case, spaces, underscores and punctuation do not change a keyword.
keyword_equivalence(_Config) ->
    K = <<"actionfeedback">>,
    K = bil_binding:keyword(<<"ACTION FEEDBACK">>),
    K = bil_binding:keyword(<<"ActionFeedback">>),
    K = bil_binding:keyword(<<"action_feedback">>),
    K = bil_binding:keyword(<<" Action-Feedback! ">>),
    <<"turnlighton2">> = bil_binding:keyword(<<"Turn.Light.On #2">>),
    <<>> = bil_binding:keyword(<<"_-- !">>),
    <<>> = bil_binding:keyword(<<>>).

%% @doc Folding and the letter/digit test are Unicode-aware.
keyword_unicode(_Config) ->
    %% Full case folding: sharp s folds to "ss".
    <<"strasse">> = bil_binding:keyword(<<"Straße"/utf8>>),
    <<"strasse">> = bil_binding:keyword(<<"STRASSE">>),
    <<"σασ"/utf8>> = bil_binding:keyword(<<"ΣΑΣ"/utf8>>),
    <<"überlicht"/utf8>> = bil_binding:keyword(<<"Über-Licht"/utf8>>),
    %% Letters of any script and decimal digits of any script stay;
    %% Unicode punctuation and spaces go.
    <<"灯1٣"/utf8>> = bil_binding:keyword(<<"灯 1\x{A0}٣。"/utf8>>),
    <<"ab">> = bil_binding:keyword(<<"a\x{2014}b\x{2003}"/utf8>>),
    %% A combining accent and the precomposed letter give the same keyword.
    <<"caf\x{E9}"/utf8>> = bil_binding:keyword(<<"Cafe\x{301}"/utf8>>),
    <<"caf\x{E9}"/utf8>> = bil_binding:keyword(<<"CAF\x{C9}"/utf8>>).

%% @doc Bytes that are not UTF-8 never make keyword/1 raise.
keyword_invalid_utf8(_Config) ->
    <<"ab1">> = bil_binding:keyword(<<"A", 255, "b-1", 16#C3>>).

%% ---------------------------------------------------------------------------
%% Rules 2 to 6
%% ---------------------------------------------------------------------------

%% @doc Category and type are matched as keywords, not as exact text.
keyword_binding(_Config) ->
    Agent = agent(<<"va">>, [comp(<<"emu">>, [], [entry(<<"actuator">>, <<"action feedback">>)])]),
    Avatar = avatar(<<"av">>, [comp(<<"act">>, [entry(<<"ACTUATOR">>, <<"ACTION_FEEDBACK">>)], [])]),
    #{bound := [#{provider := #{entity := <<"av">>, component := <<"act">>}}],
      unbound := []} = bil:bind([Agent, Avatar]).

%% @doc Two entities of the same type never bind to each other.
same_type_never_binds(_Config) ->
    A1 = avatar(<<"a1">>, [comp(<<"c1">>, [entry(<<"S">>, <<"T">>)], [entry(<<"S">>, <<"U">>)])]),
    A2 = avatar(<<"a2">>, [comp(<<"c2">>, [entry(<<"S">>, <<"U">>)], [entry(<<"S">>, <<"T">>)])]),
    #{bound := [], unbound := [#{reason := no_provider}, #{reason := no_provider}]} =
        bil:bind([A1, A2]),
    V1 = agent(<<"v1">>, [comp(<<"c1">>, [entry(<<"S">>, <<"T">>)], [entry(<<"S">>, <<"U">>)])]),
    V2 = agent(<<"v2">>, [comp(<<"c2">>, [entry(<<"S">>, <<"U">>)], [entry(<<"S">>, <<"T">>)])]),
    #{bound := [], unbound := [#{reason := no_provider}, #{reason := no_provider}]} =
        bil:bind([V1, V2]).

%% @doc An entity's consumer never binds to a service of the same entity.
own_service_never_binds(_Config) ->
    Agent = agent(<<"va">>, [comp(<<"c">>, [entry(<<"S">>, <<"T">>)], [entry(<<"S">>, <<"T">>)])]),
    #{bound := [], unbound := [#{reason := no_provider}]} = bil:bind([Agent]).

%% @doc A consumer value `no' constrains nothing.
param_no(_Config) ->
    Consumer = [entry(<<"S">>, <<"T">>, [{<<"Email">>, <<"no">>}])],
    lists:foreach(
      fun(Offered) ->
              #{bound := [_], unbound := []} =
                  bind_one(Consumer, [entry(<<"S">>, <<"T">>, Offered)])
      end,
      [[], [{<<"Email">>, <<"yes">>}], [{<<"Email">>, <<"no">>}],
       [{<<"Email">>, <<"whatever">>}], [{<<"Other">>, <<"x">>}]]).

%% @doc A consumer value `yes' needs the same parameter with value `yes'.
param_yes(_Config) ->
    Consumer = [entry(<<"S">>, <<"T">>, [{<<"Light">>, <<"yes">>}])],
    lists:foreach(
      fun({Offered, Outcome}) ->
              Outcome = outcome(bind_one(Consumer, [entry(<<"S">>, <<"T">>, Offered)]))
      end,
      [{[{<<"Light">>, <<"yes">>}], bound},
       {[{<<"LIGHT">>, <<"Yes">>}], bound},
       {[{<<"Room">>, <<"x">>}, {<<"light">>, <<" YES ">>}], bound},
       {[], parameters_mismatch},
       {[{<<"Light">>, <<"no">>}], parameters_mismatch},
       {[{<<"Light">>, <<"any">>}], parameters_mismatch},
       {[{<<"Lamp">>, <<"yes">>}], parameters_mismatch}]).

%% @doc Any other consumer value needs the same value keyword or `any'.
param_value(_Config) ->
    Consumer = [entry(<<"S">>, <<"T">>, [{<<"Room">>, <<"living room">>}])],
    lists:foreach(
      fun({Offered, Outcome}) ->
              Outcome = outcome(bind_one(Consumer, [entry(<<"S">>, <<"T">>, Offered)]))
      end,
      [{[{<<"Room">>, <<"living room">>}], bound},
       {[{<<"room">>, <<"LivingRoom">>}], bound},
       {[{<<"Room">>, <<"any">>}], bound},
       {[{<<"Room">>, <<"ANY">>}], bound},
       {[{<<"Room">>, <<"kitchen">>}], parameters_mismatch},
       {[{<<"Room">>, <<"yes">>}], parameters_mismatch},
       {[], parameters_mismatch},
       {[{<<"Hall">>, <<"living room">>}], parameters_mismatch}]).

%% @doc Every consumer parameter must hold, and a consumer `any' is a value.
param_any_consumer_value(_Config) ->
    Consumer = [entry(<<"S">>, <<"T">>, [{<<"Mode">>, <<"any">>}, {<<"Light">>, <<"yes">>}])],
    bound = outcome(bind_one(Consumer, [entry(<<"S">>, <<"T">>, [{<<"Mode">>, <<"Any">>},
                                                                {<<"Light">>, <<"yes">>}])])),
    parameters_mismatch =
        outcome(bind_one(Consumer, [entry(<<"S">>, <<"T">>, [{<<"Mode">>, <<"eco">>},
                                                            {<<"Light">>, <<"yes">>}])])),
    parameters_mismatch =
        outcome(bind_one(Consumer, [entry(<<"S">>, <<"T">>, [{<<"Mode">>, <<"any">>}])])).

%% @doc The compatible candidate with the highest score wins, whatever its place.
score_ordering(_Config) ->
    Consumer = agent(<<"va">>, [comp(<<"emu">>, [],
                                     [entry(<<"S">>, <<"T">>, [{<<"Light">>, <<"yes">>},
                                                               {<<"Room">>, <<"kitchen">>},
                                                               {<<"Email">>, <<"no">>}])])]),
    Low = avatar(<<"low">>, [comp(<<"c">>, [entry(<<"S">>, <<"T">>, [{<<"Light">>, <<"yes">>},
                                                                   {<<"Room">>, <<"any">>}])],
                                  [])]),
    Mid = avatar(<<"mid">>, [comp(<<"c">>, [entry(<<"S">>, <<"T">>, [{<<"Light">>, <<"yes">>},
                                                                   {<<"Room">>, <<"Kitchen">>}])],
                                  [])]),
    High = avatar(<<"high">>, [comp(<<"c">>, [entry(<<"S">>, <<"T">>, [{<<"Light">>, <<"yes">>},
                                                                     {<<"Room">>, <<"kitchen">>},
                                                                     {<<"Email">>, <<"no">>}])],
                                    [])]),
    #{bound := [#{provider := #{entity := <<"high">>}, score := 3, candidates := 3}]} =
        bil:bind([Consumer, Low, Mid, High]),
    #{bound := [#{provider := #{entity := <<"mid">>}, score := 2, candidates := 2}]} =
        bil:bind([Consumer, Low, Mid]),
    #{bound := [#{provider := #{entity := <<"low">>}, score := 1, candidates := 1}]} =
        bil:bind([Consumer, Low]).

%% @doc Parameter names equal as keywords count once in the score.
score_counts_names_once(_Config) ->
    Consumer = [entry(<<"S">>, <<"T">>, [{<<"Light">>, <<"no">>}, {<<"light">>, <<"no">>}])],
    #{bound := [#{score := 1}]} =
        bind_one(Consumer, [entry(<<"S">>, <<"T">>, [{<<"LIGHT">>, <<"no">>}])]),
    #{bound := [#{score := 0}]} =
        bind_one(Consumer, [entry(<<"S">>, <<"T">>, [{<<"LIGHT">>, <<"yes">>}])]).

%% @doc Equal scores go to the entity registered first.
tie_registration_order(_Config) ->
    Consumer = agent(<<"va">>, [comp(<<"emu">>, [], [entry(<<"S">>, <<"T">>, [{<<"Room">>, <<"k">>}])])]),
    First = avatar(<<"first">>, [comp(<<"z">>, [entry(<<"S">>, <<"T">>, [{<<"Room">>, <<"k">>}])], [])]),
    Second = avatar(<<"second">>, [comp(<<"a">>, [entry(<<"S">>, <<"T">>, [{<<"Room">>, <<"K">>}])], [])]),
    #{bound := [#{provider := #{entity := <<"first">>}, candidates := 2}]} =
        bil:bind([Consumer, First, Second]),
    #{bound := [#{provider := #{entity := <<"second">>}, candidates := 2}]} =
        bil:bind([Second, Consumer, First]).

%% @doc Within one entity, equal scores go to the earlier component, then the earlier service.
tie_document_order(_Config) ->
    Consumer = agent(<<"va">>, [comp(<<"emu">>, [], [entry(<<"S">>, <<"T">>)])]),
    Avatar = avatar(<<"av">>, [comp(<<"zz">>, [entry(<<"X">>, <<"Y">>)], []),
                               comp(<<"mm">>, [entry(<<"S">>, <<"T">>)], []),
                               comp(<<"aa">>, [entry(<<"S">>, <<"T">>)], [])]),
    #{bound := [#{provider := #{component := <<"mm">>}, candidates := 2}]} =
        bil:bind([Consumer, Avatar]),
    %% Services of one component share an endpoint: a later one wins only
    %% on score.
    Two = avatar(<<"av">>, [comp(<<"c">>, [entry(<<"S">>, <<"T">>, [{<<"P">>, <<"any">>}]),
                                           entry(<<"S">>, <<"T">>, [{<<"P">>, <<"1">>}])], [])]),
    Wants = fun(Params) ->
                    agent(<<"va">>, [comp(<<"emu">>, [], [entry(<<"S">>, <<"T">>, Params)])])
            end,
    #{bound := [#{score := 0, candidates := 2}]} = bil:bind([Wants([]), Two]),
    #{bound := [#{score := 1, candidates := 2}]} = bil:bind([Wants([{<<"P">>, <<"1">>}]), Two]).

%% @doc candidates counts the compatible candidates only.
candidates_count(_Config) ->
    Consumer = agent(<<"va">>, [comp(<<"emu">>, [], [entry(<<"S">>, <<"T">>, [{<<"Light">>, <<"yes">>}])])]),
    Yes = fun(Id) -> comp(Id, [entry(<<"S">>, <<"T">>, [{<<"Light">>, <<"yes">>}])], []) end,
    No = fun(Id) -> comp(Id, [entry(<<"S">>, <<"T">>, [{<<"Light">>, <<"no">>}])], []) end,
    A1 = avatar(<<"a1">>, [No(<<"n1">>), Yes(<<"y1">>), Yes(<<"y2">>)]),
    A2 = avatar(<<"a2">>, [Yes(<<"y3">>), No(<<"n2">>),
                           comp(<<"other">>, [entry(<<"S">>, <<"U">>)], [])]),
    #{bound := [#{provider := #{entity := <<"a1">>, component := <<"y1">>},
                  candidates := 3, score := 1}]} = bil:bind([Consumer, A1, A2]).

%% @doc A consumer with no (category, type) match is unbound with no_provider.
unbound_no_provider(_Config) ->
    Agent = agent(<<"va">>, [comp(<<"emu">>, [], [entry(<<"SENSOR">>, <<"Temperature">>)])]),
    Avatar = avatar(<<"av">>, [comp(<<"c">>, [entry(<<"SENSOR">>, <<"Humidity">>),
                                              entry(<<"ACTUATOR">>, <<"Temperature">>)], [])]),
    Expected = #{bound => [],
                 unbound => [#{consumer => #{entity => <<"va">>, component => <<"emu">>},
                               category => <<"SENSOR">>, type => <<"Temperature">>,
                               reason => no_provider}]},
    Expected = bil:bind([Agent, Avatar]),
    Expected = bil:bind([Agent]).

%% @doc A consumer whose candidates all fail the parameters is unbound with parameters_mismatch.
unbound_parameters_mismatch(_Config) ->
    Agent = agent(<<"va">>, [comp(<<"emu">>, [], [entry(<<"S">>, <<"T">>, [{<<"Room">>, <<"hall">>}])])]),
    Avatar = avatar(<<"av">>, [comp(<<"c1">>, [entry(<<"S">>, <<"T">>, [{<<"Room">>, <<"kitchen">>}])], []),
                               comp(<<"c2">>, [entry(<<"S">>, <<"T">>)], [])]),
    Expected = #{bound => [],
                 unbound => [#{consumer => #{entity => <<"va">>, component => <<"emu">>},
                               category => <<"S">>, type => <<"T">>,
                               reason => parameters_mismatch}]},
    Expected = bil:bind([Agent, Avatar]).

%% @doc One service may be bound by any number of consumers, of any entity.
several_consumers_one_provider(_Config) ->
    C = fun(Id) -> comp(Id, [], [entry(<<"S">>, <<"T">>), entry(<<"S">>, <<"T">>)]) end,
    V1 = agent(<<"v1">>, [C(<<"a">>), C(<<"b">>)]),
    V2 = agent(<<"v2">>, [C(<<"c">>)]),
    Avatar = avatar(<<"av">>, [comp(<<"p">>, [entry(<<"S">>, <<"T">>)], [])]),
    #{bound := Bound, unbound := []} = bil:bind([V1, Avatar, V2]),
    6 = length(Bound),
    [#{entity := <<"av">>, component := <<"p">>}] =
        lists:usort([P || #{provider := P} <- Bound]).

%% @doc Bound and unbound each list consumers in registration, then document order.
result_order(_Config) ->
    Avatar = avatar(<<"av">>, [comp(<<"a1">>, [entry(<<"S">>, <<"B">>)],
                                    [entry(<<"S">>, <<"Y">>), entry(<<"S">>, <<"Nope">>)]),
                               comp(<<"a2">>, [entry(<<"S">>, <<"C">>)],
                                    [entry(<<"S">>, <<"X">>)])]),
    Agent = agent(<<"va">>, [comp(<<"v1">>, [entry(<<"S">>, <<"X">>), entry(<<"S">>, <<"Y">>)],
                                  [entry(<<"S">>, <<"C">>), entry(<<"S">>, <<"Nada">>),
                                   entry(<<"S">>, <<"B">>)])]),
    #{bound := Bound, unbound := Unbound} = bil:bind([Avatar, Agent]),
    [{<<"av">>, <<"a1">>, <<"Y">>}, {<<"av">>, <<"a2">>, <<"X">>},
     {<<"va">>, <<"v1">>, <<"C">>}, {<<"va">>, <<"v1">>, <<"B">>}] =
        [{E, C, T} || #{consumer := #{entity := E, component := C}, type := T} <- Bound],
    [{<<"av">>, <<"Nope">>}, {<<"va">>, <<"Nada">>}] =
        [{E, T} || #{consumer := #{entity := E}, type := T} <- Unbound].

%% @doc Bindings carry the category and type as the consumer wrote them.
keeps_consumer_spelling(_Config) ->
    Agent = agent(<<"va">>, [comp(<<"emu">>, [], [entry(<<"actuator">>, <<"Turn Light On">>)])]),
    Avatar = avatar(<<"av">>, [comp(<<"act">>, [entry(<<"ACTUATOR">>, <<"TurnLightOn">>)], [])]),
    Expected = #{bound => [#{consumer => #{entity => <<"va">>, component => <<"emu">>},
                             provider => #{entity => <<"av">>, component => <<"act">>},
                             category => <<"actuator">>, type => <<"Turn Light On">>,
                             score => 0, candidates => 1}],
                 unbound => []},
    Expected = bil:bind([Agent, Avatar]).

%% @doc No descriptions, or none with consumers, bind nothing.
empty_input(_Config) ->
    Empty = #{bound => [], unbound => []},
    Empty = bil:bind([]),
    Empty = bil:bind([agent(<<"va">>, []), avatar(<<"av">>, [])]),
    Empty = bil:bind([avatar(<<"av">>, [comp(<<"c">>, [entry(<<"S">>, <<"T">>)], [])])]).

%% ---------------------------------------------------------------------------
%% Properties
%% ---------------------------------------------------------------------------

%% @doc bil:bind/1 gives exactly the naive reference's result on generated descriptions.
prop_matches_reference(_Config) ->
    check(?FORALL(Ds, descriptions(),
                  ?WHENFAIL(ct:pal("got ~p~nexpected ~p", [bil:bind(Ds), ref_bind(Ds)]),
                            collect(shape(ref_bind(Ds)),
                                    bil:bind(Ds) =:= ref_bind(Ds)))),
          ?NUMTESTS_REFERENCE).

%% @doc Every consumer entry appears exactly once in bound ++ unbound.
prop_each_consumer_once(_Config) ->
    check(?FORALL(Ds, descriptions(),
                  begin
                      #{bound := Bound, unbound := Unbound} = bil:bind(Ds),
                      Got = [{C, Cat, T} || #{consumer := C, category := Cat, type := T}
                                                <- Bound ++ Unbound],
                      Expected = [{#{entity => E, component => Id}, Cat, T}
                                  || #{entity_id := E, components := Cs} <- Ds,
                                     #{id := Id, consumes := Es} <- Cs,
                                     #{category := Cat, type := T} <- Es],
                      lists:sort(Got) =:= lists:sort(Expected)
                  end),
          ?NUMTESTS).

%% @doc Every binding's provider is an entity of the other type.
prop_provider_other_type(_Config) ->
    check(?FORALL(Ds, descriptions(),
                  begin
                      Types = maps:from_list([{E, T} || #{entity_id := E, entity_type := T} <- Ds]),
                      #{bound := Bound} = bil:bind(Ds),
                      lists:all(fun(#{consumer := #{entity := C}, provider := #{entity := P}}) ->
                                        maps:get(C, Types) =/= maps:get(P, Types)
                                end, Bound)
                  end),
          ?NUMTESTS).

%% @doc The indexed binding gives exactly what the quadratic algorithm it
%% replaced gives (bil_binding_old, kept here as the oracle).
prop_matches_old(_Config) ->
    check(?FORALL(Ds, descriptions(),
                  ?WHENFAIL(ct:pal("got ~p~nold ~p", [bil:bind(Ds), bil_binding_old:bind(Ds)]),
                            bil:bind(Ds) =:= bil_binding_old:bind(Ds))),
          ?NUMTESTS_REFERENCE).

%% @doc Same, on pairings where many providers share one (category, type)
%% and parameters decide: the case the index is for (several required
%% values, `any', `yes' and `no' mixed, many equal consumers).
prop_matches_old_shared(_Config) ->
    check(?FORALL(Ds, shared_descriptions(),
                  ?WHENFAIL(ct:pal("got ~p~nold ~p", [bil:bind(Ds), bil_binding_old:bind(Ds)]),
                            collect(shape(bil_binding_old:bind(Ds)),
                                    bil:bind(Ds) =:= bil_binding_old:bind(Ds)))),
          ?NUMTESTS).

%% @doc Same, on the shape where `any' defeats the value index: consumers
%% each requiring one of many values (and sometimes a second name, `no' or
%% `yes'), providers mostly offering `any' for them.
prop_matches_old_any(_Config) ->
    check(?FORALL(Ds, any_descriptions(),
                  ?WHENFAIL(ct:pal("got ~p~nold ~p", [bil:bind(Ds), bil_binding_old:bind(Ds)]),
                            collect(shape(bil_binding_old:bind(Ds)),
                                    bil:bind(Ds) =:= bil_binding_old:bind(Ds)))),
          ?NUMTESTS).

%% @doc Old and new agree on a generated pairing of 2,000 components a
%% side, all in two buckets.
old_matches_at_scale(_Config) ->
    {ok, Pairing} = proper_gen:pick(shared_pairing(2000, 2000), 10, {7, 8, 9}),
    Result = bil:bind(Pairing),
    Result = bil_binding_old:bind(Pairing),
    #{bound := Bound, unbound := Unbound} = Result,
    true = length(Bound) > 500 andalso length(Unbound) > 100,
    ok.

%% Shows in the PropEr output how often the generated cases exercise each
%% outcome, so a generator that stopped producing matches would be noticed.
shape(#{bound := Bound, unbound := Unbound}) ->
    {bound, bucket(length(Bound)),
     tie, bucket(length([B || #{candidates := N} = B <- Bound, N > 1])),
     scored, bucket(length([B || #{score := S} = B <- Bound, S > 0])),
     no_provider, bucket(length([U || #{reason := no_provider} = U <- Unbound])),
     mismatch, bucket(length([U || #{reason := parameters_mismatch} = U <- Unbound]))}.

bucket(0) -> none;
bucket(_) -> some.

%% ---------------------------------------------------------------------------
%% Generators: small alphabets, with spellings that differ only in case,
%% spaces and punctuation, so that matches and ties are frequent.
%% ---------------------------------------------------------------------------

descriptions() ->
    ?LET({N, Mixed}, {frequency([{1, choose(0, 1)}, {6, choose(2, 5)}]),
                      frequency([{1, false}, {4, true}])},
         ?LET(Ds, vector(N, gen_description()),
              begin
                  Named = [D#{entity_id => <<"e", (integer_to_binary(I))/binary>>}
                           || {I, D} <- lists:zip(lists:seq(1, N), Ds)],
                  case Mixed of
                      true -> mix_types(Named);
                      false -> Named
                  end
              end)).

%% Most cases should hold both entity types, or nothing could bind.
mix_types([#{entity_type := T} = First | Rest]) ->
    case [D || #{entity_type := T2} = D <- Rest, T2 =/= T] of
        [] when Rest =/= [] ->
            [First#{entity_type := other_type(T)} | Rest];
        _ ->
            [First | Rest]
    end;
mix_types([]) ->
    [].

other_type(agent) -> avatar;
other_type(avatar) -> agent.

gen_description() ->
    ?LET({Type, N}, {oneof([agent, avatar]), choose(0, 4)},
         ?LET(Cs, vector(N, component()),
              #{entity_id => <<>>, api_name => <<"API">>, entity_type => Type,
                context => <<"Generated">>,
                components => [C#{id => <<"c", (integer_to_binary(I))/binary>>}
                               || {I, C} <- lists:zip(lists:seq(1, N), Cs)]})).

component() ->
    ?LET({NS, NC}, {choose(1, 3), choose(0, 3)},
         ?LET({Ss, Cs}, {vector(NS, gen_entry()), vector(NC, gen_entry())},
              #{id => <<>>, services => Ss, consumes => Cs})).

gen_entry() ->
    ?LET({C, T, Ps}, {frequency([{6, elements(categories())}, {1, <<"SENSOR">>}]),
                      elements(types()), gen_params()},
         #{category => C, type => T, parameters => Ps}).

gen_params() ->
    ?LET(N, choose(0, 3),
         ?LET(Ps, vector(N, {elements(param_names()), elements(param_values())}),
              unique_names(Ps))).

%% Parameter element names are unique within a ServiceParameters; names
%% that are equal only as keywords may still both appear.
unique_names(Ps) ->
    lists:reverse(lists:foldl(fun({N, _} = P, Acc) ->
                                      case lists:keymember(N, 1, Acc) of
                                          true -> Acc;
                                          false -> [P | Acc]
                                      end
                              end, [], Ps)).

categories() ->
    [<<"ACTUATOR">>, <<"actuator">>, <<"Actu_ator">>, <<"Straße"/utf8>>, <<"STRASSE">>].

types() ->
    [<<"TurnOn">>, <<"turn on">>, <<"TURN_ON">>, <<"Feedback">>, <<"FEED-BACK">>].

param_names() ->
    [<<"Light">>, <<"light">>, <<"Room">>, <<"ROOM">>, <<"Email">>].

param_values() ->
    [<<"yes">>, <<"YES">>, <<"no">>, <<"No">>, <<"any">>, <<"Any">>, <<"kitchen">>,
     <<"Kit chen">>, <<"hall">>].

%% Two entities, one of each type, with up to 40 components each offering
%% and consuming one (category, type): parameters decide everything.
shared_descriptions() ->
    shared_descriptions(40).

shared_descriptions(Max) ->
    ?LET({NA, NV}, {choose(0, Max), choose(0, Max)}, shared_pairing(NA, NV)).

any_descriptions() ->
    ?LET({NA, NV}, {choose(0, 40), choose(0, 40)},
         ?LET({As, Vs}, {vector(NA, any_component(provider)), vector(NV, any_component(consumer))},
              [shared_entity(<<"av">>, avatar, As), shared_entity(<<"va">>, agent, Vs)])).

any_component(Side) ->
    ?LET(Entries, vector(1, any_entry(Side)),
         case Side of
             provider -> #{id => <<>>, services => Entries, consumes => []};
             consumer -> #{id => <<>>, services => [], consumes => Entries}
         end).

any_entry(Side) ->
    Unit = ?LET(I, choose(1, 12), <<"u", (integer_to_binary(I))/binary>>),
    Value = case Side of
                provider -> frequency([{6, <<"any">>}, {2, Unit}, {1, <<"no">>}]);
                consumer -> frequency([{8, Unit}, {1, <<"no">>}, {1, <<"yes">>}])
            end,
    Second = frequency([{3, []},
                        {1, [{elements([<<"Room">>, <<"Email">>]),
                              elements([<<"any">>, <<"no">>, <<"kitchen">>, <<"yes">>])}]}]),
    ?LET({V, Ps}, {Value, Second},
         #{category => <<"Actuator">>, type => <<"Switch">>,
           parameters => [{<<"Unit">>, V} | Ps]}).

shared_pairing(NA, NV) ->
    ?LET({As, Vs}, {vector(NA, shared_component()), vector(NV, shared_component())},
         [shared_entity(<<"av">>, avatar, As), shared_entity(<<"va">>, agent, Vs)]).

shared_entity(Id, Type, Cs) ->
    #{entity_id => Id, api_name => <<"API">>, entity_type => Type, context => <<"Shared">>,
      components => [C#{id => <<Id/binary, (integer_to_binary(I))/binary>>}
                     || {I, C} <- lists:zip(lists:seq(1, length(Cs)), Cs)]}.

shared_component() ->
    ?LET({NS, NC}, {choose(0, 2), choose(0, 3)},
         ?LET({Ss, Cs}, {vector(NS, shared_entry()), vector(NC, shared_entry())},
              #{id => <<>>, services => Ss, consumes => Cs})).

shared_entry() ->
    ?LET({T, Ps}, {frequency([{5, <<"Switch">>}, {1, <<"Dimmer">>}]),
                   list(frequency([{3, {elements([<<"Room">>, <<"room">>, <<"Unit">>, <<"Light">>]),
                                        elements([<<"yes">>, <<"no">>, <<"any">>,
                                                  <<"kitchen">>, <<"hall">>, <<"u1">>,
                                                  <<"u2">>, <<"u3">>])}},
                                   {1, {<<"Email">>, <<"no">>}}]))},
         #{category => <<"Actuator">>, type => T, parameters => lists:sublist(Ps, 4)}).

%% ---------------------------------------------------------------------------
%% Naive reference: nested loops over every pair, straight from the rules.
%% ---------------------------------------------------------------------------

ref_bind(Ds) ->
    Results = [ref_entry(E, C, Entry, Ds)
               || E <- Ds, C <- maps:get(components, E), Entry <- maps:get(consumes, C)],
    #{bound => [B || {bound, B} <- Results], unbound => [U || {unbound, U} <- Results]}.

ref_entry(#{entity_id := EId, entity_type := EType}, #{id := CId},
          #{category := Cat, type := Type} = Entry, Ds) ->
    Consumer = #{entity => EId, component => CId},
    %% Rule 2: in registration order, then document order.
    Candidates = [{#{entity => PE, component => PC}, S}
                  || #{entity_id := PE, entity_type := PT, components := PCs} <- Ds,
                     PT =/= EType,
                     #{id := PC, services := Ss} <- PCs,
                     #{category := SCat, type := SType} = S <- Ss,
                     ref_keyword(SCat) =:= ref_keyword(Cat),
                     ref_keyword(SType) =:= ref_keyword(Type)],
    Compatible = [{P, ref_score(Entry, S)} || {P, S} <- Candidates,
                                              ref_compatible(Entry, S)],
    case {Candidates, Compatible} of
        {[], _} ->
            {unbound, #{consumer => Consumer, category => Cat, type => Type,
                        reason => no_provider}};
        {_, []} ->
            {unbound, #{consumer => Consumer, category => Cat, type => Type,
                        reason => parameters_mismatch}};
        {_, _} ->
            Max = lists:max([Score || {_, Score} <- Compatible]),
            [{Provider, Max} | _] = [PS || {_, Score} = PS <- Compatible, Score =:= Max],
            {bound, #{consumer => Consumer, provider => Provider, category => Cat,
                      type => Type, score => Max, candidates => length(Compatible)}}
    end.

%% Rule 3.
ref_compatible(#{parameters := Wanted}, #{parameters := Offered}) ->
    lists:all(
      fun({N, V}) ->
              VK = ref_keyword(V),
              Has = fun(Pred) ->
                            lists:any(fun({N2, V2}) ->
                                              ref_keyword(N2) =:= ref_keyword(N)
                                                  andalso Pred(ref_keyword(V2))
                                      end, Offered)
                    end,
              if VK =:= <<"no">> -> true;
                 VK =:= <<"yes">> -> Has(fun(V2) -> V2 =:= <<"yes">> end);
                 true -> Has(fun(V2) -> V2 =:= VK orelse V2 =:= <<"any">> end)
              end
      end, Wanted).

%% Rule 4: the number of parameter names shared with equal value keywords.
ref_score(#{parameters := Wanted}, #{parameters := Offered}) ->
    length(lists:usort([ref_keyword(N) || {N, V} <- Wanted, {N2, V2} <- Offered,
                                          ref_keyword(N) =:= ref_keyword(N2),
                                          ref_keyword(V) =:= ref_keyword(V2)])).

%% Rule 1, one character at a time.
ref_keyword(Bin) ->
    Folded = unicode:characters_to_list(string:casefold(Bin)),
    unicode:characters_to_binary([C || C <- Folded, letter_or_digit(C)]).

letter_or_digit(C) ->
    re:run([C], "^[\\p{L}\\p{Nd}]$", [unicode, ucp]) =/= nomatch.

%% ---------------------------------------------------------------------------
%% Building descriptions by hand
%% ---------------------------------------------------------------------------

agent(Id, Components) -> description(Id, agent, Components).

avatar(Id, Components) -> description(Id, avatar, Components).

description(Id, Type, Components) ->
    #{entity_id => Id, api_name => <<"API">>, entity_type => Type,
      context => <<"Test">>, components => Components}.

comp(Id, Services, Consumes) ->
    #{id => Id, services => Services, consumes => Consumes}.

entry(Category, Type) -> entry(Category, Type, []).

entry(Category, Type, Parameters) ->
    #{category => Category, type => Type, parameters => Parameters}.

%% One consumer entry per description list: an Agent consuming, an Avatar offering.
bind_one(Consumes, Services) ->
    bil:bind([agent(<<"va">>, [comp(<<"emu">>, [], Consumes)]),
              avatar(<<"av">>, [comp(<<"c">>, Services, [])])]).

outcome(#{bound := [_], unbound := []}) -> bound;
outcome(#{bound := [], unbound := [#{reason := Reason}]}) -> Reason.
