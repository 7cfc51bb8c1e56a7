%% @doc Internal. Computes the Body Mapping Registry of one pairing: binds
%% every `Consumes' entry to at most one `Service' of an entity of the other
%% type, exactly as docs/bil.md section 4 says. Pure; also exports the
%% keyword normalisation that the rules compare with.
%%
%% Cost: providers are indexed by (category, type) and, inside, by
%% (parameter, value); a consumer examines only the providers that offer
%% its most selective required value (or, when it requires none, only
%% those that could score), and consumers with equal wants share one
%% result. When `any' makes every value's providers many, a consumer
%% examines only the providers offering one of its values and counts the
%% rest through the providers offering `any' for all its required names,
%% a set shared by the consumers requiring those names (choose/4). Binding
%% P services against C consumers costs O((P + C) log P) plus the
%% candidates examined, which the tests and bench/COMPLEXITY.md bound
%% (the old nested loops were P x C). What still costs in proportion to
%% the providers is an entry whose every value is offered by many
%% providers and whose parameters differ from every other entry's (a room
%% shared by a twentieth of the devices costs P/20 per entry).
-module(bil_binding).

-export([bind/1, keyword/1, explain/2]).

%% A provider after normalisation: where it lives, and its parameters'
%% value keywords by name keyword.
-record(provider, {endpoint :: bil:endpoint(),
                   params :: #{binary() => [binary()]}}).

%% The providers of one (entity type, category, type), numbered in
%% tie-break order (registration, then document order), with an inverted
%% index: for each {name keyword, value keyword}, the positions of the
%% providers offering it, ascending, and how many there are.
-record(bucket, {providers :: tuple(),
                 size :: pos_integer(),
                 postings :: #{{binary(), binary()} => {pos_integer(), [pos_integer()]}}}).

-type bucket_key() :: {bil:entity_type(), Category :: binary(), Type :: binary()}.
-type index() :: #{bucket_key() => #bucket{}}.

%% A consumer's parameters as sets: name keywords in ascending order, each
%% with its value keywords, ascending and without repeats. The rules only
%% ask whether a value is present, so this canonical form binds exactly as
%% the parameters do, and equal wants can share one result.
-type wants() :: [{Name :: binary(), Values :: [binary()]}].

-type choice() :: {bound, #provider{}, Score :: non_neg_integer(), Count :: pos_integer()}
                | {unbound, no_provider | parameters_mismatch}.

%% Results shared between consumers: a choice per bucket and wants, and
%% per bucket and set of required names the providers offering `any' for
%% all of them.
-type memo() :: #{{bucket_key(), wants()} => choice(),
                  {any, bucket_key(), [binary()]} => {non_neg_integer(), [pos_integer()]}}.

-define(YES, <<"yes">>).
-define(NO, <<"no">>).
-define(ANY, <<"any">>).

%% @doc Binds the consumers of the given descriptions, listed in
%% registration order, to the services of the other entity type.
%% Both result lists follow registration order, then document order.
-spec bind([bil:description()]) -> bil:bind_result().
bind(Descriptions) ->
    Index = index(Descriptions),
    {Bound, Unbound, _Memo} = bind_entities(Descriptions, Index, [], [], #{}),
    #{bound => lists:reverse(Bound), unbound => lists:reverse(Unbound)}.

%% @doc The keyword of a category, type, parameter name or parameter value:
%% Unicode case folding (`string:casefold/1'), then every code point that is
%% not a letter (general category L) or a decimal digit (Nd) removed, so
%% `<<"ACTION FEEDBACK">>', `<<"ActionFeedback">>' and
%% `<<"action_feedback">>' all give `<<"actionfeedback">>'. Never raises:
%% input that is not valid UTF-8 (the parsers never produce it) keeps only
%% its ASCII letters and digits.
-spec keyword(binary()) -> binary().
keyword(Bin) when is_binary(Bin) ->
    case ascii_keyword(Bin, []) of
        not_ascii ->
            case unicode:characters_to_binary(Bin) of
                Bin -> unicode_keyword(Bin);
                _Invalid -> ascii_only_keyword(Bin, [])
            end;
        Keyword ->
            Keyword
    end.

%% ---------------------------------------------------------------------------
%% Keywords
%% ---------------------------------------------------------------------------

%% For ASCII, case folding is A-Z to a-z and no other character can fold
%% into a letter or digit, so this matches the Unicode path without regexes.
%% Almost every keyword is ASCII; a list accumulator is the fastest build.
ascii_keyword(<<C, Rest/binary>>, Acc) when C < 128 ->
    ascii_keyword(Rest, ascii_char(C, Acc));
ascii_keyword(<<>>, Acc) ->
    list_to_binary(lists:reverse(Acc));
ascii_keyword(_, _Acc) ->
    not_ascii.

ascii_only_keyword(<<C, Rest/binary>>, Acc) when C >= 128 ->
    ascii_only_keyword(Rest, Acc);
ascii_only_keyword(<<C, Rest/binary>>, Acc) ->
    ascii_only_keyword(Rest, ascii_char(C, Acc));
ascii_only_keyword(<<>>, Acc) ->
    list_to_binary(lists:reverse(Acc)).

ascii_char(C, Acc) when C >= $a, C =< $z; C >= $0, C =< $9 -> [C | Acc];
ascii_char(C, Acc) when C >= $A, C =< $Z -> [C + 32 | Acc];
ascii_char(_, Acc) -> Acc.

%% NFC first, so a letter written with a combining accent and the same
%% letter precomposed give one keyword (the accent would otherwise be
%% dropped as a non-letter).
unicode_keyword(Bin) ->
    Composed = unicode:characters_to_nfc_binary(Bin),
    Folded = unicode:characters_to_binary(string:casefold(Composed)),
    re:replace(Folded, "[^\\p{L}\\p{Nd}]+", "",
               [global, unicode, ucp, {return, binary}]).

%% ---------------------------------------------------------------------------
%% Index of providers
%% ---------------------------------------------------------------------------

%% Folding from the right and prepending leaves each bucket in registration
%% then document order; positions are then given in that order.
-spec index([bil:description()]) -> index().
index(Descriptions) ->
    maps:map(fun(_Key, Providers) -> bucket(Providers) end,
             lists:foldr(fun index_entity/2, #{}, Descriptions)).

index_entity(#{entity_id := EntityId, entity_type := EntityType,
               components := Components}, Acc) ->
    lists:foldr(
      fun(#{id := ComponentId, services := Services}, Acc1) ->
              Endpoint = #{entity => EntityId, component => ComponentId},
              lists:foldr(
                fun(Service, Index) ->
                        Key = {EntityType, keyword(maps:get(category, Service)),
                               keyword(maps:get(type, Service))},
                        Provider = #provider{endpoint = Endpoint,
                                             params = provider_params(Service)},
                        maps:update_with(Key, fun(Ps) -> [Provider | Ps] end,
                                         [Provider], Index)
                end, Acc1, Services)
      end, Acc, Components).

-spec provider_params(bil:entry()) -> #{binary() => [binary()]}.
provider_params(#{parameters := Params}) ->
    lists:foldl(fun({Name, Value}, Map) ->
                        V = keyword(Value),
                        maps:update_with(keyword(Name), fun(Vs) -> [V | Vs] end,
                                         [V], Map)
                end, #{}, Params).

%% Positions are visited in descending order and prepended, so every
%% posting list comes out ascending.
bucket(Providers) ->
    Tuple = list_to_tuple(Providers),
    Size = tuple_size(Tuple),
    Postings = lists:foldl(
                 fun(Pos, Acc) ->
                         #provider{params = Params} = element(Pos, Tuple),
                         maps:fold(fun(Name, Values, Acc1) ->
                                           lists:foldl(fun(V, Acc2) -> post({Name, V}, Pos, Acc2) end,
                                                       Acc1, lists:usort(Values))
                                   end, Acc, Params)
                 end, #{}, lists:seq(Size, 1, -1)),
    #bucket{providers = Tuple, size = Size, postings = Postings}.

post(Key, Pos, Postings) ->
    case Postings of
        #{Key := {N, Ps}} -> Postings#{Key := {N + 1, [Pos | Ps]}};
        #{} -> Postings#{Key => {1, [Pos]}}
    end.

%% ---------------------------------------------------------------------------
%% Binding
%% ---------------------------------------------------------------------------

bind_entities([#{entity_id := EntityId, entity_type := EntityType,
                 components := Components} | Rest], Index, Bound, Unbound, Memo) ->
    Wanted = {other(EntityType), EntityId},
    {Bound1, Unbound1, Memo1} =
        lists:foldl(fun(Component, Acc) ->
                            bind_component(Component, Wanted, Index, Acc)
                    end, {Bound, Unbound, Memo}, Components),
    bind_entities(Rest, Index, Bound1, Unbound1, Memo1);
bind_entities([], _Index, Bound, Unbound, Memo) ->
    {Bound, Unbound, Memo}.

bind_component(#{id := ComponentId, consumes := Consumes},
               {OtherType, EntityId}, Index, Acc) ->
    Consumer = #{entity => EntityId, component => ComponentId},
    lists:foldl(fun(Entry, {Bound, Unbound, Memo}) ->
                        case bind_entry(Entry, OtherType, Index, Memo) of
                            {{bound, Provider, Score, Count}, Memo1} ->
                                {[binding(Consumer, Entry, Provider, Score, Count)
                                  | Bound], Unbound, Memo1};
                            {{unbound, Reason}, Memo1} ->
                                {Bound, [unbound(Consumer, Entry, Reason) | Unbound], Memo1}
                        end
                end, Acc, Consumes).

bind_entry(#{category := Category, type := Type} = Entry, OtherType, Index, Memo) ->
    Key = {OtherType, keyword(Category), keyword(Type)},
    case Index of
        #{Key := Bucket} ->
            Wants = wants(Entry),
            case Memo of
                #{{Key, Wants} := Choice} ->
                    {Choice, Memo};
                #{} ->
                    {Choice, Memo1} = choose(Wants, Key, Bucket, Memo),
                    {Choice, Memo1#{{Key, Wants} => Choice}}
            end;
        #{} ->
            {{unbound, no_provider}, Memo}
    end.

%% Every compatible provider offers, for each required value, that value
%% (or `any', unless the value is `yes'): the compatible ones are among the
%% providers of the required value with the fewest. With no required value
%% every provider is compatible, and only those offering `no' for a wanted
%% name can score above zero.
%%
%% When `any' makes even the fewest large (many consumers each requiring
%% a different value that most providers offer as `any'), the providers
%% are split instead: those offering one of the consumer's values (the
%% only ones that can score) are examined one by one; the others are
%% compatible exactly when they offer `any' for every required name, and
%% score 0, so they count as a whole: the providers offering `any' for
%% every required name, computed once per bucket and set of names and
%% shared by every consumer requiring those names.
-spec choose(wants(), bucket_key(), #bucket{}, memo()) -> {choice(), memo()}.
choose(Wants, Key, #bucket{size = Size, providers = Providers} = Bucket, Memo) ->
    case [candidates(Name, V, Bucket) || {Name, Values} <- Wants, V <- Values, V =/= ?NO] of
        [] ->
            Scoring = lists:umerge([positions({Name, ?NO}, Bucket) || {Name, _} <- Wants]),
            case best(Wants, Scoring, Providers, none, 0) of
                {{Provider, Score, _}, _} when Score > 0 -> {{bound, Provider, Score, Size}, Memo};
                _ -> {{bound, element(1, Providers), 0, Size}, Memo}
            end;
        [First | Sets] ->
            {Fewest, Merge} = lists:foldl(fun({N, _} = Set, {Min, _}) when N < Min -> Set;
                                             (_, Acc) -> Acc
                                          end, First, Sets),
            Offering = [posting({Name, V}, Bucket) || {Name, Values} <- Wants, V <- Values],
            case lists:sum([N || {N, _} <- Offering]) < Fewest of
                true ->
                    split(Wants, Key, [Ps || {_, Ps} <- Offering], Bucket, Memo);
                false ->
                    {chosen(best(Wants, Merge, Providers, none, 0)), Memo}
            end
    end.

chosen({_, 0}) -> {unbound, parameters_mismatch};
chosen({{Provider, Score, _Pos}, Count}) -> {bound, Provider, Score, Count}.

%% The providers offering one of the consumer's values, one by one; the
%% rest through the shared `any' set of the required names (none when a
%% `yes' is required: only its offerers can hold it).
split(Wants, Key, Offering, #bucket{providers = Providers} = Bucket, Memo) ->
    Scored = lists:umerge(Offering),
    {Best, Count} = best(Wants, Scored, Providers, none, 0),
    Required = [Name || {Name, Values} <- Wants, lists:any(fun(V) -> V =/= ?NO end, Values)],
    case lists:any(fun({_, Values}) -> lists:member(?YES, Values) end, Wants) of
        true ->
            {chosen({Best, Count}), Memo};
        false ->
            {{AnyCount, Any}, Memo1} = any_of_all(Key, Required, Bucket, Memo),
            InScored = maps:from_keys([P || P <- Scored, any_of_all(Required, element(P, Providers))],
                                      true),
            Rest = AnyCount - map_size(InScored),
            Best1 = case Rest of
                        0 -> Best;
                        _ -> better(Best, first_not_in(Any, InScored, Providers))
                    end,
            {chosen({Best1, Count + Rest}), Memo1}
    end.

%% The providers of a bucket offering `any' for every name of Names, as a
%% count and an ascending list; memoised per bucket and names.
any_of_all(Key, Names, Bucket, Memo) ->
    case Memo of
        #{{any, Key, Names} := Any} ->
            {Any, Memo};
        #{} ->
            [First | Rest] = [positions({Name, ?ANY}, Bucket) || Name <- Names],
            List = lists:foldl(fun intersect/2, First, Rest),
            Any = {length(List), List},
            {Any, Memo#{{any, Key, Names} => Any}}
    end.

any_of_all(Names, #provider{params = Params}) ->
    lists:all(fun(Name) -> lists:member(?ANY, maps:get(Name, Params, [])) end, Names).

%% Two ascending lists' common elements, ascending.
intersect([A | As], [A | Bs]) -> [A | intersect(As, Bs)];
intersect([A | As], [B | _] = Bs) when A < B -> intersect(As, Bs);
intersect([_ | _] = As, [_ | Bs]) -> intersect(As, Bs);
intersect(_, _) -> [].

%% The first position of an ascending list not in Skip (there is one: the
%% list is longer than Skip); at most map_size(Skip) steps.
first_not_in([P | Ps], Skip, Providers) ->
    case Skip of
        #{P := _} -> first_not_in(Ps, Skip, Providers);
        #{} -> {element(P, Providers), 0, P}
    end.

%% The higher score wins; among equal scores the earlier position.
better(none, B) -> B;
better({_, S1, _} = A, {_, S2, _}) when S1 > S2 -> A;
better({_, S, P1} = A, {_, S, P2}) when P1 < P2 -> A;
better(_, B) -> B.

candidates(Name, ?YES, Bucket) ->
    posting({Name, ?YES}, Bucket);
candidates(Name, V, Bucket) ->
    {N1, P1} = posting({Name, V}, Bucket),
    {N2, P2} = posting({Name, ?ANY}, Bucket),
    {N1 + N2, fun() -> lists:umerge(P1, P2) end}.

posting(Key, #bucket{postings = Postings}) ->
    maps:get(Key, Postings, {0, []}).

positions(Key, Bucket) ->
    element(2, posting(Key, Bucket)).

%% Candidates in ascending position, that is tie-break order: strictly
%% greater replaces the best so far, so among equal scores the first stays.
best(Wants, Merge, Providers, Best, Count) when is_function(Merge, 0) ->
    best(Wants, Merge(), Providers, Best, Count);
best(Wants, [Pos | Rest], Providers, Best, Count) ->
    #provider{params = Params} = Candidate = element(Pos, Providers),
    case compatible(Wants, Params) of
        false ->
            best(Wants, Rest, Providers, Best, Count);
        true ->
            Score = score(Wants, Params),
            Best1 = case Best of
                        {_, BestScore, _} when BestScore >= Score -> Best;
                        _ -> {Candidate, Score, Pos}
                    end,
            best(Wants, Rest, Providers, Best1, Count + 1)
    end;
best(_Wants, [], _Providers, Best, Count) ->
    {Best, Count}.

-spec wants(bil:entry()) -> wants().
wants(#{parameters := Params}) ->
    Grouped = lists:foldl(fun({Name, Value}, Acc) ->
                                  V = keyword(Value),
                                  maps:update_with(keyword(Name), fun(Vs) -> [V | Vs] end,
                                                   [V], Acc)
                          end, #{}, Params),
    [{N, lists:usort(Vs)} || {N, Vs} <- lists:sort(maps:to_list(Grouped))].

compatible(Wants, Offered) ->
    lists:all(fun({Name, Values}) ->
                      Has = maps:get(Name, Offered, []),
                      lists:all(fun(V) -> satisfied(V, Has) end, Values)
              end, Wants).

satisfied(?NO, _Has) -> true;
satisfied(?YES, Has) -> lists:member(?YES, Has);
satisfied(V, Has) -> lists:member(V, Has) orelse lists:member(?ANY, Has).

%% The number of distinct parameter name keywords for which the consumer and
%% the provider have a value keyword in common.
score(Wants, Offered) ->
    length([Name || {Name, Values} <- Wants,
                    shares_value(Values, maps:get(Name, Offered, []))]).

shares_value(Values, Has) ->
    lists:any(fun(V) -> lists:member(V, Has) end, Values).

binding(Consumer, #{category := Category, type := Type}, Provider, Score, Count) ->
    #{consumer => Consumer, provider => Provider#provider.endpoint,
      category => Category, type => Type, score => Score, candidates => Count}.

unbound(Consumer, #{category := Category, type := Type}, Reason) ->
    #{consumer => Consumer, category => Category, type => Type, reason => Reason}.

%% @doc Why an unbound entry of the Body Mapping Registry bound nothing,
%% for a person: each provider of its category and type (of the other
%% entity type, in tie-break order) with the consumer's parameters it does
%% not satisfy, as `{Name, Wanted, Offered}' in the consumer's spelling
%% and the provider's. `no_provider' entries have no candidates: `[]'.
%% Linear in the descriptions; meant for one entry shown on a page.
-spec explain(bil:unbound(), [bil:description()]) ->
          [#{provider := bil:endpoint(),
             failed := [{Name :: binary(), Wanted :: binary(), Offered :: [binary()]}]}].
explain(#{consumer := #{entity := E, component := C}, category := Cat, type := Type},
        Descriptions) ->
    Key = {keyword(Cat), keyword(Type)},
    case [{T, Entry} || #{entity_id := E1, entity_type := T, components := Cs} <- Descriptions,
                        E1 =:= E, #{id := C1, consumes := Us} <- Cs, C1 =:= C,
                        #{category := Ca, type := Ty} = Entry <- Us,
                        {keyword(Ca), keyword(Ty)} =:= Key] of
        [{ConsumerType, Entry} | _] ->
            Wants = [{N, V, keyword(V)} || {N, V} <- maps:get(parameters, Entry)],
            [#{provider => #{entity => PE, component => PC},
               failed => [{N, V, [PV || {PN, PV} <- Ps, keyword(PN) =:= keyword(N)]}
                          || {N, V, K} <- Wants,
                             not satisfied(K, [keyword(PV) || {PN, PV} <- Ps,
                                                              keyword(PN) =:= keyword(N)])]}
             || #{entity_id := PE, entity_type := PT, components := Cs} <- Descriptions,
                PT =:= other(ConsumerType),
                #{id := PC, services := Ss} <- Cs,
                #{category := Ca, type := Ty, parameters := Ps} <- Ss,
                {keyword(Ca), keyword(Ty)} =:= Key];
        [] ->
            []
    end.

other(agent) -> avatar;
other(avatar) -> agent.
